"""Parsed CARMEN logs kept on disk, so that a second ``jaxslam run`` on a log does not
parse it again.

Reading a log of ten thousand scans takes about a second: decompressing, NumPy's text
parser, the "no return" sentinel search, the odometry checks. A warm ``jaxslam run``
(compiled programs from :mod:`jaxslam.runtime.cache`) would spend a large part of
everything besides its filter loop there. :func:`load_carmen_cached` keeps the finished
:class:`~jaxslam.datasets.carmen.CarmenLog` in the subfolder ``logs`` of the compilation-cache folder as an uncompressed ``.npz``
(every array as stored, the other fields as JSON) and loads that in about 20 ms.

An entry is used only when everything that determines the result is equal; its file
name is the SHA-256 of

* the SHA-256 and size of the log file's bytes (a changed, replaced or renamed log
  is read again; a copy elsewhere finds the entry);
* the reader's options (``max_range``, ``on_error``, ...);
* the bytes of every ``.py`` file of the installed ``jaxslam`` package
  (:func:`jaxslam.runtime.executables.source_digest`: any edit to the reader invalidates
  every entry) and the NumPy version.

Only successful reads are stored, so a bad log raises the reader's own error every
time. An entry that cannot be read (truncated, from another build) is ignored and
replaced; writes go to a temporary file that is renamed into place, so a crash never
leaves half an entry. The folder keeps at most :data:`MAX_BYTES` (oldest entries go
first). The ``path`` of the returned log is the file the caller named.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from jaxslam.datasets.carmen import CarmenLog, load_carmen

__all__ = ["MAX_BYTES", "SUBFOLDER", "entry_path", "load_carmen_cached"]

SUBFOLDER = "logs"
FORMAT = 1
MAX_BYTES = 2 * 1024**3
"""Size of the ``logs`` folder above which the oldest entries are removed."""

_TUPLE_FIELDS = ("problems",)


def entry_path(folder: os.PathLike | str, path: os.PathLike | str, options: dict[str, Any]) -> Path:
    """The cache file of ``path`` read with ``options`` (see the module docstring)."""
    from jaxslam.runtime.executables import source_digest

    with open(path, "rb") as fh:
        content = hashlib.file_digest(fh, "sha256").hexdigest()
    size = os.path.getsize(path)
    key = json.dumps([FORMAT, content, size, sorted((k, repr(v)) for k, v in options.items()), source_digest(),
                      np.__version__])
    return Path(folder) / SUBFOLDER / (hashlib.sha256(key.encode()).hexdigest() + ".npz")


def load_carmen_cached(
    path: os.PathLike | str, folder: os.PathLike | str | None, **options: Any
) -> tuple[CarmenLog, str]:
    """:func:`jaxslam.datasets.carmen.load_carmen` with the parsed log kept in
    ``folder/logs`` (``folder`` None: no cache, a plain read).

    Returns:
        ``(log, status)``: a log equal, field by field, to ``load_carmen(path,
        **options)``, and ``"hit"`` (read from the cache), ``"stored"`` (parsed and
        stored), ``"not stored"`` (parsed; the entry could not be written) or
        ``"off"``.

    Raises:
        DataFormatError: malformed input, as :func:`~jaxslam.datasets.carmen.load_carmen`
            raises it.
        FileNotFoundError: ``path`` does not exist.
        ValueError: an option value that ``load_carmen`` refuses.
    """
    if folder is None:
        return load_carmen(path, **options), "off"
    try:
        entry = entry_path(folder, path, options)
    except OSError:
        return load_carmen(path, **options), "off"  # the reader names the missing file
    cached = _read(entry, path)
    if cached is not None:
        return cached, "hit"
    log = load_carmen(path, **options)
    return log, ("stored" if _write(entry, log) else "not stored")


def _json_default(value):
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        return float(value)
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"cannot store {type(value).__name__} in the log cache")


def _write(entry: Path, log: CarmenLog) -> bool:
    arrays: dict[str, np.ndarray] = {}
    other: dict[str, Any] = {}
    for field in dataclasses.fields(log):
        value = getattr(log, field.name)
        if isinstance(value, np.ndarray):
            arrays[f"array:{field.name}"] = value
        elif field.name != "path":
            other[field.name] = value
    try:
        meta = json.dumps(other, default=_json_default)
    except (TypeError, ValueError):
        return False  # a field this format cannot hold: do not cache
    tmp = entry.with_name(f"{entry.stem}.{os.getpid()}.tmp.npz")
    try:
        entry.parent.mkdir(parents=True, exist_ok=True)
        np.savez(tmp, __meta__=np.array(meta), **arrays)
        tmp.replace(entry)
        _trim(entry.parent)
    except OSError:  # a full or read-only disk costs the cache, not the run
        try:
            tmp.unlink(missing_ok=True)
        except OSError:
            pass
        return False
    return True


def _read(entry: Path, path) -> CarmenLog | None:
    if not entry.exists():
        return None
    try:
        with np.load(entry, allow_pickle=False) as data:
            meta = json.loads(str(data["__meta__"]))
            values = {name.split(":", 1)[1]: data[name] for name in data.files if name.startswith("array:")}
        for name in _TUPLE_FIELDS:
            if name in meta:
                meta[name] = tuple(meta[name])
        log = CarmenLog(path=Path(path), **meta, **values)
    except Exception:  # noqa: BLE001 - any unreadable entry (truncated zip, other format) is a miss
        return None
    for value in values.values():
        value.setflags(write=False)  # read-only, as the reader returns them
    os.utime(entry)  # recently used: trimmed last
    return log


def _trim(folder: Path) -> None:
    entries = sorted(folder.glob("*.npz"), key=lambda p: p.stat().st_mtime)
    total = sum(p.stat().st_size for p in entries)
    for old in entries[:-1]:
        if total <= MAX_BYTES:
            break
        total -= old.stat().st_size
        old.unlink(missing_ok=True)
