"""Victoria Park loaders on bad input: a catalogue of malformed files, each with the
error it must get, and hypothesis fuzzing of real lines (random corruptions never
raise anything but DataFormatError, and whatever loads is finite and in time order).

The default hypothesis profile (tests/conftest.py) is derandomized, so the fuzz draws
the same examples every run.
"""

from __future__ import annotations

import functools
import gzip
import io
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxslam.datasets import victoria_park as vp
from jaxslam.datasets.paths import DataFormatError, DatasetNotFoundError, find


def _data(*parts: str) -> Path:
    try:
        return find(vp.DATASET, vp.FOLDER, *parts)
    except DatasetNotFoundError as error:
        pytest.skip(str(error))


@functools.cache
def _head(parts: tuple[str, ...], count: int) -> tuple[bytes, ...]:
    """The first ``count`` lines of a real file, line ends kept."""
    with open(_data(*parts), "rb") as handle:
        return tuple(handle.readline() for _ in range(count))


@functools.cache
def _laser_records(count: int) -> bytes:
    """The first ``count`` records of the real LASER.txt stream (no line breaks)."""
    with gzip.open(_data("acfr_ascii", "LASER.txt.gz"), "rb") as stream:
        text = stream.read(count * 362 * 8)
    words = text.split()[: count * 362]
    return b"\t".join(words)


def _drs(path):
    return vp.load_dead_reckoning("ascii", path=path)


def _gps(path):
    return vp.load_gps("ascii", path=path)


# Each text loader: the real file it reads, the loader, and what it returns as times.
TEXT_FILES = {
    "DRS.txt": (("acfr_ascii", "DRS.txt"), _drs, lambda r: r.times),
    "GPS.txt": (("acfr_ascii", "GPS.txt"), _gps, lambda r: r.times),
    "measurements.dat": (("rfs_slam_ascii", "measurements.dat"), vp.load_detections, lambda r: r.times),
    "lasersampling.txt": (("ufastslam", "lasersampling.txt"), vp.load_scan_times, lambda r: r),
}


def _lines(name: str, count: int = 12, distinct: bool = False) -> list[bytes]:
    """The first ``count`` real lines; with ``distinct``, only lines whose time differs
    from the line before (detections come several to a scan)."""
    if not distinct:
        return list(_head(TEXT_FILES[name][0], count))
    lines, last = [], None
    for line in _head(TEXT_FILES[name][0], 40 * count):
        if line.split()[0] != last:
            lines.append(line)
            last = line.split()[0]
    return lines[:count]


def _write(directory: Path, name: str, data: bytes) -> Path:
    path = directory / name
    path.write_bytes(data)
    return path


# ----------------------------------------------------------------------------- catalogue


def _replace_field(line: bytes, field: int, word: bytes) -> bytes:
    parts = line.split()
    parts[field] = word
    return b"\t".join(parts) + b"\r\n"


def _catalogue():
    """(id, file name, build(lines) -> bytes, message regex, expected line or None)."""
    cases = []
    for name in TEXT_FILES:
        first = 0 if name == "lasersampling.txt" else 1  # a field that is not the time
        cases += [
            (f"{name}-empty", name, lambda ls: b"", r"no records", None),
            (f"{name}-blank-lines-only", name, lambda ls: b"\r\n\n  \n", r"no records", None),
            (f"{name}-extra-column", name, lambda ls: b"".join(ls[:2]) + ls[2].rstrip() + b" 1.0\n",
             r"expected \d numbers .* found", 3),
            (f"{name}-word", name, lambda ls, f=first: b"".join(ls[:4]) + _replace_field(ls[4], f, b"fast"),
             r"'fast' is not a number", 5),
            (f"{name}-underscore-number", name, lambda ls, f=first: b"".join(ls[:1]) + _replace_field(ls[1], f, b"1_0"),
             r"'1_0' is not a number", 2),
            (f"{name}-nan", name, lambda ls, f=first: b"".join(ls[:5]) + _replace_field(ls[5], f, b"nan"),
             r"non-finite value 'nan'", 6),
            (f"{name}-inf", name, lambda ls, f=first: b"".join(ls[:5]) + _replace_field(ls[5], f, b"-inf"),
             r"non-finite value '-inf'", 6),
            (f"{name}-overflow", name, lambda ls, f=first: b"".join(ls[:5]) + _replace_field(ls[5], f, b"1e999"),
             r"non-finite value '1e999'", 6),
            (f"{name}-nul-byte", name, lambda ls: b"".join(ls[:6]) + b"\x00" + ls[6], r"unexpected character", 7),
            (f"{name}-latin1", name, lambda ls: b"".join(ls[:2]) + b"\xe9" + ls[2], r"unexpected character", 3),
            (f"{name}-time-backwards", name, lambda ls: b"".join(ls[:3]) + ls[4] + ls[3] + b"".join(ls[5:]),
             r"times must", 5),
            (f"{name}-truncated-gzip", name, lambda ls: gzip.compress(b"".join(ls))[:-12],
             r"gzip stream is truncated or corrupt", None),
            (f"{name}-corrupt-gzip", name, lambda ls: _flip(gzip.compress(b"".join(ls)), 14),
             r"gzip stream is truncated or corrupt", None),
        ]
        if name != "lasersampling.txt":  # there, a line without its one column is blank
            cases.append((f"{name}-missing-column", name,
                          lambda ls: b"".join(ls[:3]) + b" ".join(ls[3].split()[:-1]) + b"\n",
                          r"expected \d numbers .* found", 4))
        if name != "measurements.dat":  # detections may share a time (several per scan)
            cases.append((f"{name}-time-repeats", name, lambda ls: b"".join(ls[:3]) + ls[2] + b"".join(ls[3:]),
                          r"times must increase", 4))
    cases += [
        ("measurements.dat-negative-range", "measurements.dat",
         lambda ls: b"".join(ls[:2]) + _replace_field(ls[2], 1, b"-3.0"), r"range > 0", 3),
        ("measurements.dat-bearing-out-of-range", "measurements.dat",
         lambda ls: b"".join(ls[:2]) + _replace_field(ls[2], 2, b"4.0"), r"bearing in \[0, pi\]", 3),
        ("measurements.dat-negative-diameter", "measurements.dat",
         lambda ls: _replace_field(ls[0], 3, b"-0.2") + b"".join(ls[1:]), r"diameter >= 0", 1),
    ]
    return cases


def _flip(data: bytes, index: int) -> bytes:
    return data[:index] + bytes([data[index] ^ 0xFF]) + data[index + 1:]


CATALOGUE = _catalogue()


@pytest.mark.parametrize("case", CATALOGUE, ids=[c[0] for c in CATALOGUE])
def test_bad_text_input_gets_a_data_format_error(case, tmp_path):
    _, name, build, message, line = case
    load = TEXT_FILES[name][1]
    path = _write(tmp_path, name, build(_lines(name, distinct=True)))
    with pytest.raises(DataFormatError, match=message) as error:
        load(path)
    assert error.value.path == str(path) and str(error.value).startswith(str(path))
    if line is not None:
        assert error.value.line == line, str(error.value)


def test_line_numbers_count_blank_lines(tmp_path):
    lines = _lines("DRS.txt")
    path = _write(tmp_path, "DRS.txt", lines[0] + b"\r\n\r\n" + lines[2] + lines[1])
    with pytest.raises(DataFormatError, match="times must increase") as error:
        _drs(path)
    assert error.value.line == 5
    mac = _write(tmp_path, "GPS.txt", b"0.0 1.0 2.0\r1.0 1.0\r")  # old Mac line ends
    with pytest.raises(DataFormatError, match="found 2") as error:
        _gps(mac)
    assert error.value.line == 2


def test_gzipped_text_without_gz_suffix_loads(tmp_path):
    lines = _lines("DRS.txt")
    plain = _drs(_write(tmp_path, "plain.txt", b"".join(lines)))
    packed = _drs(_write(tmp_path, "packed.txt", gzip.compress(b"".join(lines))))
    np.testing.assert_array_equal(plain.times, packed.times)
    np.testing.assert_array_equal(plain.steering, packed.steering)


def test_real_truncated_laser_gzip(tmp_path):
    data = _data("acfr_ascii", "LASER.txt.gz").read_bytes()
    path = _write(tmp_path, "LASER.txt.gz", data[: len(data) // 3])
    with pytest.raises(DataFormatError, match=r"truncated or corrupt after \d+ complete records") as error:
        vp.load_laser(path)
    assert error.value.line == 1  # the stream has no line breaks


def test_laser_stream_errors_name_record_field_and_line(tmp_path):
    words = _laser_records(3).split(b"\t")
    cases = [
        (words[:362 + 101] + [b"x1"] + words[363 + 101:], r"'x1' is not a number \(record 2, field 102 of 362\)"),
        (words[:-10], r"record 3 is incomplete"),
        (words[:362] + [b"nan"] + words[363:], r"scan time 'nan' is not finite \(record 2, field 1"),
        (words[362:724] + words[:362] + words[724:], r"times must increase"),
        ([], r"no records"),
    ]
    for tokens, message in cases:
        path = _write(tmp_path, "LASER.txt", b"\t".join(tokens))
        with pytest.raises(DataFormatError, match=message):
            vp.load_laser(path)
    with pytest.raises(DataFormatError, match=r"LASER\.txt, line 2: 'x1'"):
        vp.read_laser_text(_write(tmp_path, "LASER.txt", b"\t".join(words[:362]) + b"\n" + b"\t".join(
            words[362:400] + [b"x1"] + words[401:])))


def test_laser_range_policy_counts_every_oddity(tmp_path):
    words = _laser_records(3).split(b"\t")
    clean = vp.load_laser(_write(tmp_path, "clean.txt", b"\t".join(words)))
    odd = list(words)
    odd[1], odd[2], odd[362 + 5], odd[724 + 7], odd[724 + 8] = b"nan", b"inf", b"-inf", b"0", b"-2.5"
    laser = vp.load_laser(_write(tmp_path, "odd.txt", b"\t".join(odd)))
    assert laser.meta["laser_invalid_ranges"] == 5
    assert laser.meta["laser_no_return_beams"] == clean.meta["laser_no_return_beams"] - int(
        sum(float(odd_word) > vp.NO_RETURN_M for odd_word in (words[1], words[2], words[367], words[731], words[732]))
    )
    replaced = laser.ranges != clean.ranges
    assert replaced.sum() == 5 and np.all(laser.ranges[replaced] == np.float32(vp.NO_RETURN_VALUE))
    assert np.all(np.isfinite(laser.ranges)) and laser.ranges.min() > 0
    # the same policy on the .npz form
    ranges = clean.ranges.copy()
    ranges[0, :3] = np.nan
    path = tmp_path / "laser.npz"
    np.savez(path, time_s=clean.times, ranges_m=ranges)
    assert vp.load_laser(path).meta["laser_invalid_ranges"] == 3


def test_sequence_meta_counts_the_recovered_oddities():
    _data("mat", "aa3_dr.npz")
    seq = vp.load_sequence(max_steps=50)
    assert seq.meta["recovered"] == {"observations_beyond_max_range": seq.meta["n_dropped_range"]}
    extracted = vp.load_sequence("extractor", max_steps=50)
    assert set(extracted.meta["recovered"]) == {
        "observations_beyond_max_range", "laser_no_return_beams", "laser_invalid_ranges"
    }
    assert extracted.meta["recovered"]["laser_no_return_beams"] > 0
    with pytest.raises(ValueError, match="max_steps"):
        vp.load_sequence(max_steps=0)


def _npz_bytes(**arrays) -> bytes:
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    return buffer.getvalue()


def _real_dr_npz(count: int = 40) -> dict[str, np.ndarray]:
    with np.load(_data("mat", "aa3_dr.npz")) as archive:
        return {name: archive[name][:count] for name in ("time", "speed", "steering")}


def test_bad_npz_inputs(tmp_path):
    dr = _real_dr_npz()
    nan_speed = dict(dr, speed=np.where(np.arange(40) == 7, np.nan, dr["speed"]))
    backwards = dict(dr, time=dr["time"][[0, 1, 3, 2] + list(range(4, 40))])
    cases = [
        (b"", r"not a readable \.npz"),
        (b"PK\x03\x04 not really a zip", r"not a readable \.npz"),
        (_npz_bytes(**dr)[:200], r"not a readable \.npz"),
        (b"time speed steering\n1 2 3\n", r"not a readable \.npz"),
        (_npz_bytes(time=dr["time"], speed=dr["speed"]), r"missing array 'steering'"),
        (_npz_bytes(**nan_speed), r"record 8: speed is not finite"),
        (_npz_bytes(**dict(dr, steering=dr["steering"][:-1])), r"arrays differ in length"),
        (_npz_bytes(**dict(dr, speed=np.array(["a"] * 40))), r"array 'speed' has dtype <U1, not numbers"),
        (_npz_bytes(**{k: v[:0] for k, v in dr.items()}), r"is empty: no records"),
        (_npz_bytes(**backwards), r"record 4: time .* times must increase"),
    ]
    for data, message in cases:
        path = _write(tmp_path, "aa3_dr.npz", data)
        with pytest.raises(DataFormatError, match=message):
            vp.load_dead_reckoning(path=path)
    single = tmp_path / "single.npy"
    np.save(single, dr["time"])
    with pytest.raises(DataFormatError, match="single array"):
        vp.load_dead_reckoning(path=single.rename(tmp_path / "single.npz"))
    with pytest.raises(DataFormatError, match="is a directory"):
        vp.load_dead_reckoning(path=_mkdir(tmp_path / "dir.npz"))
    with pytest.raises(DataFormatError, match="is a directory"):
        vp.load_scan_times(_mkdir(tmp_path / "dir.txt"))
    with pytest.raises(FileNotFoundError):
        vp.load_scan_times(tmp_path / "absent.txt")


def _mkdir(path: Path) -> Path:
    path.mkdir()
    return path


def test_detection_off_the_scan_times_names_the_line(monkeypatch, tmp_path):
    lines = _lines("measurements.dat", 30)
    bad = list(lines)
    bad[24] = _replace_field(lines[24], 0, b"1.280")  # the last detection of scan 2, 1 ms late
    real = find

    def redirect(dataset, *parts):
        if parts[-1] == "measurements.dat":
            return _write(tmp_path, "measurements.dat", b"".join(bad))
        return real(dataset, *parts)

    _data("mat", "aa3_dr.npz")
    monkeypatch.setattr(vp, "find", redirect)
    with pytest.raises(DataFormatError, match=r"measurements\.dat, line 25: detection at t = 1\.280 s falls on no"):
        vp.load_sequence(max_steps=20)


# ----------------------------------------------------------------------------- fuzzing


_TOKENS = st.sampled_from(
    [b"", b"nan", b"NaN", b"-inf", b"inf", b"1e999", b"-1e999", b"-1", b"0", b"1e-320", b"abc", b"1_0", b"0x1",
     b"99999999999999999999", b"\x00", b"\xff\xfe", b"+", b".", b"1e", b"--1", b"\t", b"\r", b"\n", b"81.91"]
)


@st.composite
def _corrupted(draw, lines: list[bytes]) -> bytes:
    lines = list(lines)
    for _ in range(draw(st.integers(1, 4))):
        index = draw(st.integers(0, len(lines) - 1))
        parts = lines[index].split()
        position = draw(st.integers(0, max(len(parts) - 1, 0)))
        kind = draw(st.sampled_from(["token", "delete", "insert", "cut", "bytes", "swap", "dup", "drop", "digit"]))
        if kind == "token" and parts:
            parts[position] = draw(_TOKENS)
        elif kind == "delete" and parts:
            del parts[position]
        elif kind == "insert":
            parts.insert(position, draw(_TOKENS))
        elif kind == "cut":
            joined = b" ".join(parts)
            parts = [joined[: draw(st.integers(0, len(joined)))]]
        elif kind == "bytes":
            parts.insert(position, draw(st.binary(max_size=8)))
        elif kind == "digit" and parts:
            word = parts[position]
            at = draw(st.integers(0, len(word)))
            parts[position] = word[:at] + draw(st.sampled_from([b"9", b"-", b".", b"e", b"5e3"])) + word[at:]
        elif kind == "swap":
            other = draw(st.integers(0, len(lines) - 1))
            lines[index], lines[other] = lines[other], lines[index]
            continue
        elif kind == "dup":
            lines.insert(index, lines[index])
            continue
        elif kind == "drop" and len(lines) > 1:
            del lines[index]
            continue
        lines[index] = b"\t".join(parts) + draw(st.sampled_from([b"\n", b"\r\n", b""]))
    data = b"".join(lines)
    if draw(st.booleans()) and draw(st.booleans()):
        packed = gzip.compress(data)
        data = packed[: draw(st.integers(0, len(packed)))] if draw(st.booleans()) else packed
    return data


@pytest.fixture(scope="module")
def scratch():
    with tempfile.TemporaryDirectory() as directory:
        yield Path(directory)


def _check_loaded(result, times: np.ndarray, strict: bool) -> None:
    for value in ([result] if isinstance(result, np.ndarray) else vars(result).values()):
        if isinstance(value, np.ndarray):
            assert np.all(np.isfinite(value))
    steps = np.diff(times)
    assert np.all(steps > 0) if strict else np.all(steps >= 0)


@pytest.mark.parametrize("name", sorted(TEXT_FILES))
@settings(max_examples=150, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_fuzzed_real_lines_raise_only_data_format_error(name, scratch, data):
    _, load, times_of = TEXT_FILES[name]
    blob = data.draw(_corrupted(_lines(name)))
    path = _write(scratch, name, blob)
    try:
        result = load(path)
    except DataFormatError as error:
        assert error.path == str(path)
        text_lines = blob.count(b"\n") + blob.count(b"\r") + 1
        assert error.line is None or 1 <= error.line <= text_lines or blob[:2] == b"\x1f\x8b"
        return
    _check_loaded(result, times_of(result), strict=name != "measurements.dat")


@settings(max_examples=100)
@given(data=st.data())
def test_fuzzed_laser_stream_raises_only_data_format_error(data):
    words = _laser_records(2).split(b"\t")
    for _ in range(data.draw(st.integers(1, 3))):
        index = data.draw(st.integers(0, len(words) - 1))
        kind = data.draw(st.sampled_from(["token", "delete", "insert", "newline"]))
        if kind == "token":
            words[index] = data.draw(_TOKENS)
        elif kind == "delete":
            del words[index]
        elif kind == "insert":
            words.insert(index, data.draw(_TOKENS))
        else:
            words[index] = words[index] + b"\r\n"
    blob = b"\t".join(words)
    if data.draw(st.booleans()):
        packed = gzip.compress(blob)
        blob = packed[: data.draw(st.integers(0, len(packed)))]
    with tempfile.TemporaryDirectory() as directory:
        path = _write(Path(directory), "LASER.txt.gz", blob)
        try:
            laser = vp.load_laser(path)
        except DataFormatError as error:
            assert error.path == str(path)
            return
    assert laser.ranges.shape == (laser.times.size, vp.N_BEAMS)
    assert np.all(np.isfinite(laser.ranges)) and np.all(laser.ranges > 0)
    assert np.all(np.diff(laser.times) > 0)


@settings(max_examples=100)
@given(data=st.data())
def test_fuzzed_npz_bytes_raise_only_data_format_error(data):
    blob = bytearray(_npz_bytes(**_real_dr_npz(20)))
    kind = data.draw(st.sampled_from(["flip", "cut"]))
    if kind == "flip":
        for _ in range(data.draw(st.integers(1, 4))):
            blob[data.draw(st.integers(0, len(blob) - 1))] ^= data.draw(st.integers(1, 255))
    else:
        blob = blob[: data.draw(st.integers(0, len(blob)))]
    with tempfile.TemporaryDirectory() as directory:
        path = _write(Path(directory), "aa3_dr.npz", bytes(blob))
        try:
            dr = vp.load_dead_reckoning(path=path)
        except DataFormatError:
            return
    assert np.all(np.isfinite(dr.speed)) and np.all(np.diff(dr.times) > 0)
