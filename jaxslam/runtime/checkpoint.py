"""Checkpoints of a chunked filter run: save atomically, refuse what does not fit.

A checkpoint is one ``.npz`` file holding every leaf of the scan carry (particles,
maps, weights; the random keys are per step inputs derived from the seed, so the
position in the log is all that is needed to continue the random stream), the
per-step outputs produced so far, the position in the log, and a JSON
*fingerprint* of the run (algorithm, dataset, particles, seed, configuration). It is
written to a temporary file, flushed to disk and renamed over the old one, so a
crash while saving leaves the previous checkpoint intact.

Loading checks the fingerprint, the pytree structure and every leaf's shape and
dtype against the run being resumed; a corrupt file or any mismatch raises
:class:`CheckpointError` that names the file and the problem.

A checkpoint also records :func:`code_digest`, a digest of jaxslam's own source and of
the JAX and jaxlib versions, and only the same digest resumes it. Another version can
run other programs (a new default, such as another reach of the loop-closure search,
a change in the order of float operations, or another XLA) while the state keeps
its shapes, so a resumed run would silently join two versions' runs, equal to neither
one's straight run.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import jax
import numpy as np

FORMAT_VERSION = 1


class CheckpointError(ValueError):
    """A checkpoint cannot be used (corrupt, or from another run)."""


@functools.lru_cache(maxsize=1)
def code_digest() -> str:
    """A short SHA-256 digest of the jaxslam package's source (the relative path and
    the bytes of every ``.py`` file in it) and of the JAX and jaxlib versions, whose
    compiler builds the programs (see the module docstring)."""
    import jaxlib

    root = Path(__file__).resolve().parents[1]
    digest = hashlib.sha256(f"jax {jax.__version__} jaxlib {jaxlib.__version__}\0".encode())
    for path in sorted(root.rglob("*.py")):
        digest.update(path.relative_to(root).as_posix().encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()[:16]


def _leaves(tree) -> tuple[list[Any], Any]:
    leaves, treedef = jax.tree_util.tree_flatten(tree)
    return leaves, treedef


@dataclass
class Checkpoint:
    """Where and how often to checkpoint a run, and what identifies the run.

    Attributes:
        path: the checkpoint file (``.npz``).
        every: save every ``every`` steps (and at the end of the run).
        fingerprint: JSON-able description of the run; a resume must match it.
        resume: load ``path`` (if it exists) before running.
        static: JSON-able static settings that shape the state and may change during
            a run (a grown map layout); saved with every checkpoint and read back by
            :meth:`saved_static` before the state is restored.
    """

    path: Path
    every: int | None = None
    fingerprint: dict[str, Any] = field(default_factory=dict)
    resume: bool = False
    static: dict[str, Any] = field(default_factory=dict)
    _last_saved: int = 0

    def __post_init__(self):
        self.path = Path(self.path)

    def due(self, done: int) -> bool:
        return self.every is not None and done - self._last_saved >= self.every

    def steps_to_save(self, done: int) -> int | None:
        """Steps from ``done`` to the next save (at least 1), or None without ``every``:
        the chunked runner ends a chunk there (:func:`jaxslam.runtime.progress.run_scan_chunked`)."""
        return None if self.every is None else max(1, self._last_saved + self.every - done)

    def save(self, carry, done: int, output_leaves: list[np.ndarray]) -> None:
        """Write the carry, the outputs of steps ``0..done-1`` and the position, atomically."""
        leaves, treedef = _leaves(carry)
        arrays: dict[str, np.ndarray] = {f"carry_{i}": np.asarray(leaf) for i, leaf in enumerate(leaves)}
        for i, leaf in enumerate(output_leaves):
            arrays[f"out_{i}"] = np.asarray(leaf)
        meta = {
            "format": FORMAT_VERSION,
            "code": code_digest(),
            "done": int(done),
            "fingerprint": json.loads(json.dumps(self.fingerprint, sort_keys=True, default=str)),
            "carry_treedef": str(treedef),
            "n_carry": len(leaves),
            "n_out": len(output_leaves),
            "static": json.loads(json.dumps(self.static, sort_keys=True, default=str)),
        }
        arrays["meta_json"] = np.frombuffer(json.dumps(meta, sort_keys=True).encode(), dtype=np.uint8)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.path.with_name(self.path.name + ".tmp")
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, self.path)
        self._last_saved = done

    def saved_static(self) -> dict[str, Any]:
        """The ``static`` settings stored in :attr:`path` (empty if none)."""
        return self._meta(self._read()).get("static", {})

    def _read(self) -> dict[str, np.ndarray]:
        where = str(self.path)
        if not self.path.exists():
            raise CheckpointError(f"{where}: no checkpoint to resume from")
        try:
            with np.load(self.path, allow_pickle=False) as data:
                return {name: data[name] for name in data.files}
        except (OSError, ValueError, zipfile.BadZipFile, EOFError) as err:
            raise CheckpointError(f"{where}: corrupt checkpoint ({err})") from None

    def _meta(self, files: dict[str, np.ndarray]) -> dict[str, Any]:
        where = str(self.path)
        if "meta_json" not in files:
            raise CheckpointError(f"{where}: not a jaxslam checkpoint (no metadata)")
        try:
            meta = json.loads(files["meta_json"].tobytes().decode())
        except (UnicodeDecodeError, json.JSONDecodeError) as err:
            raise CheckpointError(f"{where}: corrupt checkpoint metadata ({err})") from None
        if meta.get("format") != FORMAT_VERSION:
            raise CheckpointError(f"{where}: checkpoint format {meta.get('format')} is not {FORMAT_VERSION}")
        return meta

    def load(self, carry_template) -> tuple[Any, int, list[np.ndarray]]:
        """``(carry, done, output_leaves)`` from :attr:`path`, validated against the run."""
        return self._load(carry_template, whole=True)

    def load_leading(self, template) -> tuple[Any, int, list[np.ndarray]]:
        """Like :meth:`load`, but restores only the saved carry's first leaves, in the
        structure of ``template`` (checked leaf by leaf): the state of a ``(state,
        params)`` carry, for a caller that supplies the parameters anew."""
        return self._load(template, whole=False)

    def _load(self, carry_template, whole: bool) -> tuple[Any, int, list[np.ndarray]]:
        where = str(self.path)
        files = self._read()
        meta = self._meta(files)
        if meta.get("code") != code_digest():
            raise CheckpointError(
                f"{where}: written by another version of jaxslam or JAX (digest {meta.get('code')!r}, this "
                f"version's {code_digest()!r}); resuming would join two versions' runs: resume with the version "
                "that wrote it, or start the run again")
        mine = json.loads(json.dumps(self.fingerprint, sort_keys=True, default=str))
        theirs = meta.get("fingerprint", {})
        differing = sorted(k for k in set(mine) | set(theirs) if mine.get(k) != theirs.get(k))
        if differing:
            details = "; ".join(f"{k}: checkpoint {theirs.get(k)!r}, this run {mine.get(k)!r}" for k in differing)
            raise CheckpointError(f"{where}: checkpoint is from a different run ({details})")
        leaves, treedef = _leaves(carry_template)
        if whole and (meta["carry_treedef"] != str(treedef) or meta["n_carry"] != len(leaves)):
            raise CheckpointError(f"{where}: the filter state's structure differs from this run's")
        if len(leaves) > meta["n_carry"]:
            raise CheckpointError(f"{where}: holds {meta['n_carry']} state arrays, this run needs {len(leaves)}")
        restored = []
        for i, leaf in enumerate(leaves):
            saved = files.get(f"carry_{i}")
            if saved is None:
                raise CheckpointError(f"{where}: state array {i} is missing")
            if saved.shape != np.shape(leaf) or saved.dtype != np.asarray(leaf).dtype:
                raise CheckpointError(
                    f"{where}: state array {i} has shape {saved.shape} {saved.dtype}, "
                    f"this run needs {np.shape(leaf)} {np.asarray(leaf).dtype}"
                )
            restored.append(saved)
        missing = [i for i in range(meta["n_out"]) if f"out_{i}" not in files]
        if missing:
            raise CheckpointError(f"{where}: output arrays {missing} are missing")
        outputs = [files[f"out_{i}"] for i in range(meta["n_out"])]
        self._last_saved = int(meta["done"])
        # device_put, not jnp.asarray: the latter is a small program per array
        carry = jax.tree_util.tree_unflatten(treedef, [jax.device_put(a) for a in restored])
        return carry, int(meta["done"]), outputs
