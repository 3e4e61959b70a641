"""The one strict reader of input files: plain text, gzip and ``.npz``.

Every loader (CARMEN logs, Victoria Park, relations files, TUM trajectories, the
perturbation tools) reads its bytes through here, so that the same problems get the
same :class:`~jaxslam.datasets.paths.DataFormatError`, naming the file, the line and the
problem:

* a directory where a file was expected: ``is a directory, not a <kind>``;
* a gzip stream (recognised by its magic bytes, whatever the suffix) that is truncated
  or corrupt: ``gzip stream is truncated or corrupt after N complete <unit> (...);
  re-download the file``, at the line after the last complete one;
* a character that is not printable ASCII (:func:`check_printable`, for formats
  that are ASCII by definition);
* an ``.npz`` archive that is unreadable, holds a single array, lacks an array, or
  holds an empty or non-numeric one (:func:`load_npz`);
* in a whitespace-separated numeric table (:func:`numeric_rows`, or the stricter
  :func:`read_table`, which also refuses ``1_000`` and unprintable characters): a row
  with another number of fields, a field that is not a number or not finite;
* columns that are not finite, differ in length, or times that go backwards
  (:func:`finite_columns`, :func:`same_length`, :func:`check_increasing`).

Text is decoded as ASCII with every other byte replaced by U+FFFD, so a stray byte
shows up as what it is rather than as a decoding traceback. A missing file raises
:class:`FileNotFoundError` (loaders that know a dataset raise
:class:`~jaxslam.datasets.paths.DatasetNotFoundError` before reading).
"""

from __future__ import annotations

import gzip
import io
import math
import os
import re
import zlib
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from jaxslam.datasets.paths import DataFormatError

GZIP_MAGIC = b"\x1f\x8b"

# Printable ASCII and the usual whitespace; anything else (NUL, other control bytes,
# non-ASCII, which decodes to U+FFFD) is reported as such rather than as a bad number.
_UNPRINTABLE = re.compile(r"[^\x20-\x7e\t\n\r\v\f]")


def complete_lines(partial: bytes) -> tuple[str, int, int]:
    """``(unit, complete, line)`` of a truncated stream counted in lines: the number of
    whole lines read and the line the stream broke in."""
    complete = partial.count(b"\n")
    return "lines", complete, complete + 1


def read_bytes(
    path: os.PathLike | str,
    kind: str = "data file",
    progress: Callable[[bytes], tuple[str, int, int]] = complete_lines,
) -> bytes:
    """The bytes of ``path``, gunzipped when they start with the gzip magic.

    Args:
        path: the file.
        kind: what the file should be, for the directory message ("a CARMEN log").
        progress: for a truncated or corrupt gzip stream, maps the bytes decoded so far
            to ``(unit, complete units, line)`` for the message; by default lines.

    Raises:
        DataFormatError: ``path`` is a directory, or its gzip stream is truncated or
            corrupt.
    """
    try:
        with open(path, "rb") as handle:
            data = handle.read()
    except IsADirectoryError:
        raise DataFormatError(path, None, f"is a directory, not a {kind}") from None
    if data[:2] != GZIP_MAGIC:
        return data
    chunks: list[bytes] = []
    try:
        with gzip.GzipFile(fileobj=io.BytesIO(data)) as stream:
            while chunk := stream.read(1 << 16):  # small reads: a truncation is located closely
                chunks.append(chunk)
    except (EOFError, OSError, zlib.error) as error:
        unit, complete, line = progress(b"".join(chunks))
        raise DataFormatError(
            path, line,
            f"gzip stream is truncated or corrupt after {complete} complete {unit} "
            f"({type(error).__name__}: {error}); re-download the file",
        ) from None
    return b"".join(chunks)


def read_text(
    path: os.PathLike | str,
    kind: str = "data file",
    progress: Callable[[bytes], tuple[str, int, int]] = complete_lines,
) -> str:
    """:func:`read_bytes` decoded as ASCII, other bytes replaced by U+FFFD."""
    return read_bytes(path, kind, progress).decode("ascii", errors="replace")


def check_printable(path: os.PathLike | str, text: str) -> None:
    """Raise naming the line of the first character that is not printable ASCII."""
    match = _UNPRINTABLE.search(text)
    if match is not None:
        line = text.count("\n", 0, match.start()) + 1
        raise DataFormatError(path, line, f"unexpected character {match.group()!r} (not printable ASCII)")


def numeric_rows(
    path: os.PathLike | str, fields: str, kind: str, commas: bool = False
) -> Iterator[tuple[int, tuple[float, ...]]]:
    """Yield ``(line_number, values)`` for each row of a whitespace-separated text
    table whose columns are named by ``fields`` (e.g. ``"t1 t2 x y z roll pitch yaw"``).

    Blank lines and lines starting with ``#`` are skipped; ``commas`` also accepts
    commas as separators. A directory, a row with another number of fields, a field
    that is not a number or not finite raise :class:`~jaxslam.datasets.paths.DataFormatError`
    naming the file and line; ``kind`` names the expected file type in the directory message.
    """
    names = fields.split()
    text = read_text(path, kind)
    for line_number, line in enumerate(text.split("\n"), start=1):
        tokens = (line.replace(",", " ") if commas else line).split()
        if not tokens or tokens[0].startswith("#"):
            continue
        if len(tokens) != len(names):
            raise DataFormatError(
                path, line_number, f"expected {len(names)} fields '{fields}', got {len(tokens)}"
            )
        try:
            values = tuple(float(token) for token in tokens)
        except ValueError:
            raise DataFormatError(path, line_number, "a field is not a number") from None
        if not all(math.isfinite(value) for value in values):
            raise DataFormatError(path, line_number, "a field is not finite")
        yield line_number, values


def load_npz(path: os.PathLike | str, names: list[str]) -> dict[str, np.ndarray]:
    """The named arrays of an ``.npz`` archive, each checked to be numeric and non-empty;
    anything else is a :class:`~jaxslam.datasets.paths.DataFormatError`."""
    path = Path(path)
    # A damaged archive fails deep inside zipfile/zlib/NumPy with many exception types
    # (BadZipFile, zlib.error, EOFError, NotImplementedError for a garbled version
    # field, ValueError for a bad array header ...): every one means "unreadable".
    try:
        archive = np.load(path, allow_pickle=False)
    except IsADirectoryError:
        raise DataFormatError(path, None, "is a directory, not a data file") from None
    except FileNotFoundError:
        raise
    except Exception as error:  # noqa: BLE001 (see above)
        raise DataFormatError(path, None, f"not a readable .npz archive ({type(error).__name__}: {error})") from None
    if not isinstance(archive, np.lib.npyio.NpzFile):
        raise DataFormatError(path, None, "holds a single array, not an .npz archive of named arrays")
    arrays = {}
    with archive:
        for name in names:
            if name not in archive.files:
                raise DataFormatError(path, None, f"missing array {name!r} (has {sorted(archive.files)})")
            try:
                array = np.asarray(archive[name])
            except Exception as error:  # noqa: BLE001 (see above)
                raise DataFormatError(
                    path, None, f"array {name!r} is unreadable ({type(error).__name__}: {error})"
                ) from None
            if array.dtype.kind not in "iuf":
                raise DataFormatError(path, None, f"array {name!r} has dtype {array.dtype}, not numbers")
            if array.size == 0:
                raise DataFormatError(path, None, f"array {name!r} is empty: no records")
            arrays[name] = array
    return arrays


def parse_floats(words: list[str]) -> tuple[np.ndarray | None, int | None]:
    """``(values, None)``, or ``(None, index of the first word that is not a number)``.

    Python's and NumPy's float parsers accept ``1_000``; a data file never means that,
    so words with an underscore are refused too.
    """
    try:
        values = np.array(words, dtype=np.float64)
    except ValueError:
        values = None
    if values is not None and not any("_" in word for word in words):
        return values, None
    bad = next(i for i, word in enumerate(words) if "_" in word or not _is_float(word))
    return None, bad


def _is_float(word: str) -> bool:
    try:
        float(word)
    except ValueError:
        return False
    return True


def read_records(path: Path, n_columns: int, what: str) -> tuple[np.ndarray, np.ndarray]:
    """Parse a line-per-record numeric table; ``(table (N, n_columns), line numbers (N,))``."""
    text = read_text(path)
    check_printable(path, text)
    words: list[str] = []
    line_numbers: list[int] = []
    for number, line in enumerate(text.replace("\r\n", "\n").replace("\r", "\n").split("\n"), start=1):
        parts = line.split()
        if not parts:
            continue
        if len(parts) != n_columns:
            raise DataFormatError(
                path, number, f"expected {n_columns} numbers ({what}), found {len(parts)}: {line.strip()[:80]!r}"
            )
        words.extend(parts)
        line_numbers.append(number)
    if not line_numbers:
        raise DataFormatError(path, None, f"no records ({what})")
    lines = np.asarray(line_numbers, dtype=np.int64)
    values, bad = parse_floats(words)
    if values is None:
        raise DataFormatError(
            path, int(lines[bad // n_columns]),
            f"{words[bad][:40]!r} is not a number (field {bad % n_columns + 1} of {n_columns}: {what})",
        )
    finite = np.isfinite(values)
    if not finite.all():
        bad = int(np.argmin(finite))
        raise DataFormatError(
            path, int(lines[bad // n_columns]),
            f"non-finite value {words[bad][:40]!r} (field {bad % n_columns + 1} of {n_columns}: {what})",
        )
    return values.reshape(-1, n_columns), lines


def read_table(path: os.PathLike | str, n_columns: int, what: str) -> np.ndarray:
    """Read a whitespace-separated numeric table, one record per line.

    Blank lines are skipped; LF, CRLF and CR line ends are accepted; a gzip stream is
    recognised by its first bytes. Every problem (wrong column count, a word that is not
    a number, a non-finite value, a character that is not printable ASCII, a truncated
    or corrupt gzip stream, no records at all) raises
    :class:`~jaxslam.datasets.paths.DataFormatError` naming the file and line.

    Args:
        path: the file.
        n_columns: the number of numbers each line must hold.
        what: the column names, for the error message.

    Returns:
        (N, n_columns) float64.
    """
    return read_records(Path(path), n_columns, what)[0]


def _record_label(lines: np.ndarray | None, k: int) -> tuple[int | None, str]:
    """Line number of record ``k`` (text files) or ``None`` and a record label (arrays)."""
    if lines is None:
        return None, f"record {k + 1}: "
    return int(lines[k]), ""


def check_increasing(path: Path, times: np.ndarray, strict: bool, lines: np.ndarray | None = None) -> None:
    """Raise if ``times`` ever decreases (or repeats, when ``strict``); names the line or record."""
    steps = np.diff(times)
    bad = np.nonzero(steps <= 0 if strict else steps < 0)[0]
    if bad.size:
        k = int(bad[0]) + 1
        line, label = _record_label(lines, k)
        order = "increase" if strict else "not decrease"
        raise DataFormatError(
            path, line, f"{label}time {times[k]:.3f} s after {times[k - 1]:.3f} s: times must {order}"
        )


def finite_columns(path: Path, **columns: np.ndarray) -> None:
    """Raise naming the first record of any column that is not finite."""
    for name, values in columns.items():
        finite = np.isfinite(values)
        if not finite.all():
            k = int(np.argmin(finite.reshape(finite.shape[0], -1).all(axis=1)))
            raise DataFormatError(path, None, f"record {k + 1}: {name} is not finite")


def same_length(path: Path, **columns: np.ndarray) -> None:
    lengths = {name: int(values.shape[0]) for name, values in columns.items()}
    if len(set(lengths.values())) > 1:
        raise DataFormatError(path, None, f"arrays differ in length: {lengths}")
