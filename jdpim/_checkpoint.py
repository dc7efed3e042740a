"""Runs that survive interruption: finished blocks of paths (subset simulation: levels) kept on disk.

A checkpoint is a directory of part files, one per finished block of paths (``paths<k>-block<b>.npz``: the
``k``-th run of paths of the job) or subset-simulation level (``level<i>.npz``), each in the ``.npz`` format of
``result.save`` (:mod:`jdpim._io`): the job's fingerprint (digests of the scene, the method and the question),
what the part covers, and its arrays. A part is written to a temporary file and moved into place
(``os.replace``), so a kill at any moment leaves every part already there whole. A resumed job loads the parts it
finds and computes only the others; every path is a pure function of its row (its key or point), so the result
is bit for bit that of an uninterrupted run. When the job finishes the part files are deleted.
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime
import hashlib
import json
import os
import re

import numpy as np

from ._io import ENTRY, FORMAT, _classes, _decode, _NotStored, _Writer, versions
from ._pytree import check_int

_PART = re.compile(r"^(paths\d+-block\d+|level\d+)\.npz$")  # the part files a checkpoint writes (and deletes)
_TEMPORARY = re.compile(r"^(paths\d+-block\d+|level\d+)\.npz\.\d+\.tmp$")  # one being written (left by a kill)


@dataclasses.dataclass(frozen=True)
class Checkpoint:
    """Where a long run keeps its finished work, to resume after an interruption (``jdpim.solve(...,
    checkpoint=...)``, ``jdpim.first_passage(..., checkpoint=...)``).

    Args:
        path: a directory (created if missing) for the part files; one job per directory.
        every: most paths per block of a sampling method (DPIM, Monte Carlo), each block written when finished
            (``None``: 16 chunks per device, the blocks a long run streams anyway). Subset simulation writes
            every level.

    The same call with the same scene, method (seed, sizes, ``chunk_size``, devices) and question resumes from
    the finished parts and gives the result bit for bit; a checkpoint of another job is refused in one line. The
    part files are deleted when the job finishes (``docs/persistence.md``).
    """

    path: str
    every: int | None = None

    def __post_init__(self):
        if not isinstance(self.path, (str, os.PathLike)):
            raise TypeError(f"checkpoint path must be a str or os.PathLike, got {self.path!r}")
        object.__setattr__(self, "path", os.fspath(self.path))
        if self.every is not None:
            check_int("every", self.every, low=1)


def as_checkpoint(value) -> Checkpoint | None:
    """``value`` (``None``, a path or a :class:`Checkpoint`) as a :class:`Checkpoint` or ``None``."""
    if value is None or isinstance(value, Checkpoint):
        return value
    if isinstance(value, (str, os.PathLike)):
        return Checkpoint(value)
    raise TypeError(f"checkpoint must be None, a path or a jdpim.Checkpoint, got {value!r}")


def _fingerprint(value) -> dict:
    """``{"digest", "text"}`` of a scene, method or question: SHA-256 of its encoding in the file format (its
    ``repr``, memory addresses left out, where it holds Python functions), and a short description. A method's
    ``progress`` setting does not count."""
    if dataclasses.is_dataclass(value) and "progress" in {f.name for f in dataclasses.fields(value)}:
        value = dataclasses.replace(value, progress=None)  # a progress line does not change a result
    text = re.sub(r" at 0x[0-9a-fA-F]+", "", repr(value))
    sha = hashlib.sha256()
    writer = _Writer(_classes())
    try:
        sha.update(json.dumps(writer.encode(value, "x"), sort_keys=True).encode())
    except _NotStored:
        writer.arrays = {}
        sha.update(text.encode())
    for name, arr in writer.arrays.items():
        sha.update(f"{name}{arr.dtype.str}{arr.shape}".encode())
        sha.update(np.ascontiguousarray(arr).tobytes())
    return {"digest": sha.hexdigest(), "text": text if len(text) <= 160 else text[:157] + "..."}


def digest(array) -> str:
    """SHA-256 of an array's dtype, shape and bytes (what a part covers: the rows of a run of paths)."""
    arr = np.ascontiguousarray(np.asarray(array))
    return hashlib.sha256(f"{arr.dtype.str}{arr.shape}".encode() + arr.tobytes()).hexdigest()


class Session:
    """One job's use of a :class:`Checkpoint`: loads and writes its parts, counts its runs of paths."""

    def __init__(self, checkpoint: Checkpoint, parts: dict):
        self.checkpoint, self.every = checkpoint, checkpoint.every
        self.fingerprint = {k: _fingerprint(v) for k, v in parts.items()}
        self.runs = 0
        os.makedirs(checkpoint.path, exist_ok=True)
        for name in sorted(os.listdir(checkpoint.path)):
            if _PART.match(name):
                self._check(name, self._document(name)["fingerprint"])

    def _file(self, name: str) -> str:
        return os.path.join(self.checkpoint.path, name)

    def _document(self, name: str) -> dict:
        with np.load(self._file(name), allow_pickle=False) as npz:
            return json.loads(str(npz[ENTRY]))

    def _check(self, name: str, saved: dict) -> None:
        for part, now in self.fingerprint.items():
            then = saved.get(part, {})
            if then.get("digest") != now["digest"]:
                raise ValueError(
                    f"checkpoint {self._file(name)} is of another {part} ({then.get('text')}; this run: "
                    f"{now['text']}): resume with the same scene, method and question, or use another path"
                )

    def next_run(self) -> int:
        """The index of the job's next run of paths (runs come in the same order on every resume)."""
        self.runs += 1
        return self.runs - 1

    def load(self, name: str, covers: dict):
        """The arrays of part ``name`` (``None`` if not written yet); refused if it covers other than ``covers``."""
        if not os.path.exists(self._file(name)):
            return None
        with np.load(self._file(name), allow_pickle=False) as npz:
            doc = json.loads(str(npz[ENTRY]))
            arrays = {k: npz[k] for k in npz.files if k != ENTRY}
        self._check(name, doc["fingerprint"])
        if doc["covers"] != covers:
            raise ValueError(
                f"checkpoint {self._file(name)} covers {doc['covers']}, this run {covers}: resume with the same "
                "every, chunk_size and devices, or use another path"
            )
        return _decode(doc["part"], arrays, {}, doc["versions"]["jdpim"])

    def store(self, name: str, covers: dict, part) -> None:
        """Write part ``name`` (a tuple or dict of arrays and numbers) atomically: a temporary file, then
        ``os.replace``."""
        writer = _Writer({})
        doc = {
            "format": FORMAT,
            "type": "Checkpoint",
            "versions": versions(),
            "created": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "fingerprint": self.fingerprint,
            "covers": covers,
            "part": writer.encode(part, "part"),
        }
        final = self._file(name)
        temporary = f"{final}.{os.getpid()}.tmp"
        with open(temporary, "wb") as fh:
            np.savez(fh, **{ENTRY: np.array(json.dumps(doc, allow_nan=False))}, **writer.arrays)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(temporary, final)

    def remove(self) -> None:
        """Delete the part files (the job finished) and any a kill left half-written, and the directory if that
        leaves it empty."""
        for name in os.listdir(self.checkpoint.path):
            if _PART.match(name) or _TEMPORARY.match(name):
                os.remove(self._file(name))
        with contextlib.suppress(OSError):
            os.rmdir(self.checkpoint.path)


@contextlib.contextmanager
def session(checkpoint, **parts):
    """A :class:`Session` of ``checkpoint`` (``None``, a path or a :class:`Checkpoint`) for the job described by
    ``parts`` (scene, method, question); its parts are deleted when the body finishes without an exception."""
    checkpoint = as_checkpoint(checkpoint)
    if checkpoint is None:
        yield None
        return
    import jax

    if jax.process_count() > 1:
        raise ValueError("checkpoint applies to a run in one process, not under jax.distributed")
    ses = Session(checkpoint, parts)
    yield ses
    ses.remove()
