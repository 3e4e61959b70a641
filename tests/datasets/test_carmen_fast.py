"""The bulk (NumPy) CARMEN reader against the line-by-line reference reader: the same
arrays, counts, messages and skips, on real logs and on randomly corrupted ones."""

from __future__ import annotations

import dataclasses
import gzip
import tempfile
from pathlib import Path
from unittest import mock

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxslam.datasets import carmen, registry
from jaxslam.datasets.paths import DataFormatError, DatasetNotFoundError
from jaxslam.datasets.reader import read_bytes
from jaxslam.datasets.registry import lookup
from tests.datasets.test_carmen import _corrupted_log


def _load(path_or_name, slow: bool, **options):
    """``(log, None)`` or ``(None, error message)``, with the bulk path on or off."""
    loader = registry.load_dataset_log if isinstance(path_or_name, str) else carmen.load_carmen
    try:
        if slow:
            with mock.patch.object(carmen, "read_lines_fast", lambda *args: None):
                return loader(path_or_name, **options), None
        return loader(path_or_name, **options), None
    except DataFormatError as error:
        return None, str(error)


def _assert_same(fast, slow) -> None:
    for field in dataclasses.fields(fast):
        a, b = getattr(fast, field.name), getattr(slow, field.name)
        if isinstance(a, np.ndarray):
            assert a.dtype == b.dtype and a.shape == b.shape, field.name
            assert np.array_equal(a, b, equal_nan=True), field.name
        else:
            assert a == b, field.name


@pytest.mark.parametrize("name", ["intel", "mit-csail", "intel-corrected", "orebro-corrected"])
def test_bulk_reader_equals_line_reader_on_real_logs(name):
    try:
        path = lookup(name).paths()[0]
    except DatasetNotFoundError as error:
        pytest.skip(str(error))
    text = read_bytes(path)
    assert carmen.read_lines_fast(text, None, 1.0) is not None  # the bulk path is taken
    (fast, _), (slow, _) = _load(name, False), _load(name, True)
    _assert_same(fast, slow)


def _flaser(ranges, t, host=b"host") -> bytes:
    values = b" ".join(repr(float(r)).encode() for r in ranges)
    return b"FLASER %d %s 1 2 0.5 1 2 0.5 %r %s %r\n" % (len(ranges), values, t, host, t + 0.01)


def test_bulk_reader_falls_back_for_what_it_does_not_handle(tmp_path):
    base = [b"PARAM robot_front_laser_max 30 nohost 0\n", b"ODOM 1 2 0.1 0 0 0 5.0 host 5.0\n",
            _flaser([1.0, 2.0, 3.0], 10.0), _flaser([1.0, 40.0, float("nan")], 10.5), b"NEFF 3 1 h 1\n"]
    cases = {
        "clean": (base, True),
        "big backstep": (base + [_flaser([1.0, 2.0, 3.0], 8.0)], False),
        "small backstep": (base + [_flaser([1.0, 2.0, 3.0], 10.2)], True),
        "two beam counts": (base + [_flaser([1.0, 2.0], 11.0)], False),
        "extra field": (base + [_flaser([1.0, 2.0, 3.0], 11.0).replace(b"host", b"host x")], False),
        "missing field": (base + [_flaser([1.0, 2.0, 3.0], 11.0).replace(b" 0.5 ", b" ", 1)], False),
        "nan pose": (base + [_flaser([1.0, 2.0, 3.0], 11.0).replace(b" 0.5 ", b" nan ", 1)], False),
        "text range": (base + [_flaser([1.0, 2.0, 3.0], 11.0).replace(b" 2.0 ", b" x ", 1)], False),
        "bad odom": (base + [b"ODOM 1 2 inf 0 0 0 6.0 host 6.0\n"], False),
        "short odom": (base + [b"ODOM 1 2 0 0 0 6.0 host 6.0\n"], False),
        "odom back": (base + [b"ODOM 1 2 0.1 0 0 0 4.0 host 4.0\n"], True),
        "robotlaser first": ([b"ROBOTLASER1 0 -1.57 3.14 1.57 20 0.1 0 3 1 2 3 0 0 0 0 0 0 0 0 0 0 0 0 1 h 1\n"]
                             + base, False),
        "robotlaser after": (base + [b"ROBOTLASER1 0 -1.57 3.14 1.57 20 0.1 0 1 1 0 0 0 0 0 0 0 0 0 0 0 0 1 h 1\n"],
                             True),
        "comment and blank": ([b"# x\n", b"\n", b"   \n"] + base, True),
        "crlf": ([line.replace(b"\n", b"\r\n") for line in base], True),
    }
    for name, (lines, bulk) in cases.items():
        path = tmp_path / f"{name.replace(' ', '_')}.clf"
        path.write_bytes(b"".join(lines))
        assert (carmen.read_lines_fast(path.read_bytes(), None, 1.0) is not None) == bulk, name
        for on_error in ("raise", "skip"):
            (fast, fast_error), (slow, slow_error) = _load(path, False, on_error=on_error), _load(
                path, True, on_error=on_error)
            assert fast_error == slow_error, name
            if fast is not None:
                _assert_same(fast, slow)


@settings(max_examples=120, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(_corrupted_log(), st.sampled_from(["raise", "skip"]), st.sampled_from(["raise", "pad"]))
def test_fuzz_bulk_reader_equals_line_reader(case, on_error, mixed_geometry):
    data, compress = case
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "fuzz.clf"
        path.write_bytes(gzip.compress(data) if compress else data)
        options = {"on_error": on_error, "mixed_geometry": mixed_geometry}
        (fast, fast_error), (slow, slow_error) = _load(path, False, **options), _load(path, True, **options)
        assert fast_error == slow_error
        if fast is not None:
            _assert_same(fast, slow)
