"""The parameter specifications: every name ``--set`` accepts, its default as typed,
and its allowed values."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from jaxslam.app import params
from jaxslam.grid.types import get_path, param_paths
from jaxslam.datasets.registry import ALGORITHMS


def _params_defaults(algorithm):
    if ALGORITHMS[algorithm] == "landmark":
        from jaxslam.feature.params import Params

        return Params()
    from jaxslam.grid.algorithms import grid_algorithm

    return grid_algorithm(algorithm).make_params(np.zeros(1), dtype=np.float64)


def _value(values, name):
    """A landmark filter's field, or a grid filter's leaf by its path."""
    return get_path(values, name) if "." in name else getattr(values, name)


@pytest.mark.parametrize("algorithm", sorted(ALGORITHMS))
def test_each_default_reads_back_and_is_allowed(algorithm):
    defaults, values = params.defaults(algorithm), _params_defaults(algorithm)
    for name, spec in params.specs(algorithm).items():
        exact = float(_value(values, name))
        assert np.float32(float(defaults[name])) == np.float32(exact), name  # as the filters read it
        assert spec.problem(exact) is None, (name, exact, spec.allowed())
        assert params.check_value(algorithm, name, exact) == name


@given(st.floats(min_value=-1e12, max_value=1e12, allow_nan=False))
def test_a_value_is_shown_as_typed_and_reads_back(value):
    """The shortest text that reads back as the same float32, with the digits written
    out between 1e-4 and 1e6 (``20``, not ``2e+01``)."""
    text = params.typed(value)
    assert np.float32(float(text)) == np.float32(value)
    if 1e-4 <= abs(value) < 1e6:
        assert "e" not in text, text


@pytest.mark.parametrize("algorithm", sorted(ALGORITHMS))
def test_every_scalar_field_is_specified(algorithm):
    values = _params_defaults(algorithm)
    names = values._fields if ALGORITHMS[algorithm] == "landmark" else param_paths()
    scalar = {n for n in names if isinstance(_value(values, n), (int, float)) or np.ndim(_value(values, n)) == 0}
    scalar -= {"geometry", "sensor_offset", "ut_predict", "ut_update", "ut_landmark"}
    from jaxslam.feature.params import PARAMETER_SPECS as LANDMARK
    from jaxslam.grid.types import PARAMETER_SPECS as GRID

    family = LANDMARK if ALGORITHMS[algorithm] == "landmark" else GRID
    assert set(family) == scalar


def test_reference_covers_exactly_what_set_accepts():
    rows = params.parameter_reference()
    names = [row.name for row in rows]
    assert len(names) == len(set(names))
    accepted = {name for algorithm in ALGORITHMS for name in params.specs(algorithm)}
    assert set(names) == accepted
    assert {"sensor.beam_angles", "sensor.laser_offset"}.isdisjoint(names) and "gmapping.str" in names
    for row in rows:
        assert isinstance(row, params.ParamRow) and row.unit and row.meaning
        assert set(row.defaults) == {a for a in ALGORITHMS if row.name in params.specs(a)}
    by_name = {row.name: row for row in rows}
    assert by_name["matcher.score_sigma"].defaults["srupf-gm"] == "0.05"
    assert by_name["keyframes.linear_update"].defaults == {"srupf-gm": "0.5", "srupf-gm-npc": "0.5", "gmapping": "1"}
    assert set(by_name["gmapping.srr"].defaults) == {"gmapping"}


@pytest.mark.parametrize("algorithm", ["srupf-gm", "erb-upf"])
def test_list_params_prints_the_table(run_cli, algorithm):
    status, out, _ = run_cli("run", "--list-params", "--algorithm", algorithm)
    assert status == 0
    lines = out.strip().splitlines()
    assert lines[0].split()[:4] == ["name", "default", "unit", "meaning"]
    assert [line.split()[0] for line in lines[1:]] == list(params.specs(algorithm))


@given(value=st.floats(allow_nan=True, allow_infinity=True))
def test_a_standard_deviation_must_be_finite_and_positive(value):
    spec = params.specs("srupf-gm")["matcher.score_sigma"]
    assert (spec.problem(value) is None) == (math.isfinite(value) and value > 0)


def test_vectors_from_a_calibration_file():
    assert params.check_value("srupf-gm", "srupf.match_noise", [0.02, 0.02, 0.01], "--params f:") == "srupf.match_noise"
    with pytest.raises(ValueError, match=r"match_noise\[1\]=nan"):
        params.check_value("srupf-gm", "srupf.match_noise", [0.02, float("nan"), 0.01], "--params f:")
    with pytest.raises(ValueError, match="expected 3"):
        params.check_value("srupf-gm", "srupf.match_noise", [0.02], "--params f:")
