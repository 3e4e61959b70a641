"""The parsed-log cache (jaxslam.datasets.log_cache): same log as the reader, keyed by
content, options and code, robust to bad entries, and used by `jaxslam run`."""

from __future__ import annotations

import dataclasses
import os

import numpy as np
import pytest

from jaxslam.app import data
from jaxslam.datasets import log_cache
from jaxslam.datasets.carmen import load_carmen
from jaxslam.datasets.log_cache import entry_path, load_carmen_cached
from jaxslam.datasets.paths import DataFormatError
from tests.datasets.test_carmen import GOOD, _flaser, _write


def assert_same_log(a, b):
    for field in dataclasses.fields(a):
        x, y = getattr(a, field.name), getattr(b, field.name)
        if isinstance(x, np.ndarray):
            assert isinstance(y, np.ndarray), field.name
            assert x.dtype == y.dtype and x.shape == y.shape, field.name
            assert np.array_equal(x, y, equal_nan=x.dtype.kind == "f"), field.name
            assert not y.flags.writeable, field.name
        else:
            assert x == y and type(x) is type(y), (field.name, x, y)


def test_hit_equals_a_fresh_read(tmp_path):
    log_path = _write(tmp_path, GOOD, compress=True)
    folder = tmp_path / "cache"
    first, status = load_carmen_cached(log_path, folder)
    assert status == "stored"
    second, status = load_carmen_cached(log_path, folder)
    assert status == "hit"
    fresh = load_carmen(log_path)
    assert_same_log(fresh, first)
    assert_same_log(fresh, second)
    assert len(list((folder / "logs").glob("*.npz"))) == 1


def test_shipped_log_round_trip(tmp_path):
    """A real log with every kind of field (no-return decision, repair, PARAMs)."""
    from jaxslam.datasets.paths import DatasetNotFoundError
    from jaxslam.datasets.registry import lookup

    try:
        path = lookup("mit-csail").paths()[0]
    except DatasetNotFoundError as error:
        pytest.skip(str(error))
    assert load_carmen_cached(path, tmp_path)[1] == "stored"
    cached, status = load_carmen_cached(path, tmp_path)
    assert status == "hit"
    assert_same_log(load_carmen(path), cached)


def test_changed_file_and_other_options_are_read_again(tmp_path):
    log_path = _write(tmp_path, GOOD)
    folder = tmp_path / "cache"
    before, _ = load_carmen_cached(log_path, folder)
    # Same size and a restored mtime: only the content tells the change.
    stat = os.stat(log_path)
    text = log_path.read_text().replace("4.5", "4.4")
    log_path.write_text(text)
    os.utime(log_path, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    after, status = load_carmen_cached(log_path, folder)
    assert status == "stored"
    assert after.ranges[1, 3] == np.float32(4.4) and before.ranges[1, 3] == np.float32(4.5)
    clipped, status = load_carmen_cached(log_path, folder, max_range=3.0)
    assert status == "stored"
    assert clipped.max_range == 3.0 and after.max_range != 3.0
    assert entry_path(folder, log_path, {}) != entry_path(folder, log_path, {"max_range": 3.0})


def test_source_digest_is_part_of_the_key(tmp_path, monkeypatch):
    import jaxslam.runtime.executables as executables

    log_path = _write(tmp_path, GOOD)
    a = entry_path(tmp_path, log_path, {})
    monkeypatch.setattr(executables, "source_digest", lambda: "another build")
    assert entry_path(tmp_path, log_path, {}) != a


def test_broken_entry_is_replaced(tmp_path):
    log_path = _write(tmp_path, GOOD)
    folder = tmp_path / "cache"
    load_carmen_cached(log_path, folder)
    entry = entry_path(folder, log_path, {})
    entry.write_bytes(entry.read_bytes()[:100])  # truncated
    log, status = load_carmen_cached(log_path, folder)
    assert status == "stored"
    assert_same_log(load_carmen(log_path), log)
    assert load_carmen_cached(log_path, folder)[1] == "hit"


def test_bad_log_raises_every_time_and_is_not_stored(tmp_path):
    bad = _write(tmp_path, GOOD + [_flaser([1.0, 2.0, 3.0, 4.0], 11.0).replace("4.0", "x")])
    folder = tmp_path / "cache"
    for _ in range(2):
        with pytest.raises(DataFormatError, match="log.clf"):
            load_carmen_cached(bad, folder)
    assert not list(folder.rglob("*.npz"))
    with pytest.raises(FileNotFoundError):
        load_carmen_cached(tmp_path / "missing.clf", folder)


def test_off_and_unwritable_folder(tmp_path):
    log_path = _write(tmp_path, GOOD)
    assert load_carmen_cached(log_path, None)[1] == "off"
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    log, status = load_carmen_cached(log_path, blocker)
    assert status == "not stored"
    assert_same_log(load_carmen(log_path), log)


def test_folder_is_trimmed_oldest_first(tmp_path, monkeypatch):
    monkeypatch.setattr(log_cache, "MAX_BYTES", 1)
    folder = tmp_path / "cache"
    paths = [_write(tmp_path, GOOD[:-1] + [_flaser([1.5, 2.5, 3.5, 4.5 + i], 10.2)], name=f"log{i}.clf")
             for i in range(3)]
    for path in paths:
        load_carmen_cached(path, folder)
    left = list((folder / "logs").glob("*.npz"))
    assert left == [entry_path(folder, paths[-1], {})]


def test_run_loads_through_the_cache(tmp_path, monkeypatch):
    log_path = _write(tmp_path, GOOD)
    monkeypatch.setattr(data, "log_cache_folder", lambda: str(tmp_path / "cache"))
    assert data.load_log(None, log_path, 0, None, None)[1] == "stored"
    log, status = data.load_log(None, log_path, 0, None, 3.0)
    assert status == "stored" and log.max_range == 3.0
    assert data.load_log(None, log_path, 0, None, None)[1] == "hit"
    monkeypatch.setattr(data, "log_cache_folder", lambda: None)
    assert data.load_log(None, log_path, 0, None, None)[1] == "off"
