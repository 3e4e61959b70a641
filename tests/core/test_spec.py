"""A swappable part is given as a function or by its name; an unknown name is refused."""

import pytest

from jaxslam.core.resampling import RESAMPLERS, get_resampler, systematic
from jaxslam.core.spec import choose
from jaxslam.grid.matching import MATCHERS, get_matcher


def test_choose_takes_a_function_or_its_name_and_refuses_an_unknown_name():
    def own(*args):
        return args

    assert choose({"s": systematic}, "s", "resampler") is systematic
    assert choose({"s": systematic}, own, "resampler") is own
    with pytest.raises(ValueError, match=r"unknown matcher 'x'; choose one of \['a', 'b'\]"):
        choose({"b": own, "a": own}, "x", "matcher")


def test_the_resampler_and_matcher_tables_are_looked_up_by_choose():
    assert all(get_resampler(name) is fn for name, fn in RESAMPLERS.items())
    assert all(get_matcher(name) is fn for name, fn in MATCHERS.items())
    with pytest.raises(ValueError, match="unknown matcher"):
        get_matcher("nearest")
