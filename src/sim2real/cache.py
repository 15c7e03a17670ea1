"""Work kept between rounds of the loop: a rung whose inputs did not change is read back, not refitted.

A round of the loop adds one line to ``model.yaml``; every rung before it has the same effects, data,
settings and code as in the round before, so its fit is the same to the last bit. :class:`FitCache`
keeps each expensive piece of work (a rung's fit, a link's diagnosis, the bodies' mesh bounds; the gap
report's replays and figures) in a file named by the digest of
everything it depends on (:func:`digest`): the data and the nominal model as arrays, the effects, the
settings, the package's own source and the versions of the numerical libraries. A hit is exactly what
the work would compute; a miss (or an unreadable file) computes it. Entries neither this round nor the round
before used are pruned: a line removed again (or a model.yaml put back as it was) is read back, not refitted.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import os
import pickle
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

T = TypeVar("T")

# The libraries whose arithmetic a fit's last bits depend on.
NUMERIC_LIBRARIES = ("numpy", "scipy", "cvxpy", "clarabel", "scs", "pinocchio", "mujoco")

# The file in a cache's directory holding the start of the last round that pruned it (FitCache.prune).
ROUND_MARK = ".last_round"


@functools.lru_cache(maxsize=1)
def code_digest() -> str:
    """The sim2real package's files and the numerical libraries' versions: a fit made by other code is
    never read back."""
    from importlib import metadata

    package = Path(__file__).resolve().parents[1]
    hasher = hashlib.sha256()
    for path in sorted(p for p in package.rglob("*") if p.is_file() and "__pycache__" not in p.parts):
        hasher.update(path.relative_to(package).as_posix().encode() + b"\0" + path.read_bytes() + b"\0")
    for name in NUMERIC_LIBRARIES:
        try:
            version = metadata.version(name)
        except metadata.PackageNotFoundError:
            version = "-"
        hasher.update(f"{name}={version}\0".encode())
    return hasher.hexdigest()


def _feed(hasher: Any, value: Any) -> None:
    """Feed ``value`` to ``hasher`` with its type and structure, so different values never share a stream."""
    if value is None or isinstance(value, (bool, int, float, str, bytes, np.generic)):
        hasher.update(f"{type(value).__name__}:{value!r};".encode())
    elif isinstance(value, np.ndarray):
        array = np.ascontiguousarray(value)
        hasher.update(f"array:{array.dtype.str}:{array.shape};".encode())
        if array.dtype == object:
            for item in array.reshape(-1):
                _feed(hasher, item)
        else:
            hasher.update(array.tobytes())
    elif isinstance(value, dict):
        hasher.update(f"dict:{len(value)};".encode())
        for key in sorted(value, key=repr):
            _feed(hasher, key)
            _feed(hasher, value[key])
    elif isinstance(value, (list, tuple)):
        hasher.update(f"{type(value).__name__}:{len(value)};".encode())
        for item in value:
            _feed(hasher, item)
    elif isinstance(value, slice):
        hasher.update(f"slice:{value.start}:{value.stop}:{value.step};".encode())
    elif isinstance(value, Path):
        hasher.update(f"path:{value.as_posix()};".encode())
    elif dataclasses.is_dataclass(value) and not isinstance(value, type):
        hasher.update(f"{type(value).__qualname__};".encode())
        for item in dataclasses.fields(value):
            field_value = getattr(value, item.name)
            # a lazily computed cache (a regressor) follows from the other fields; a callable computes one
            if not callable(field_value) and not item.name.startswith("_"):
                _feed(hasher, item.name)
                _feed(hasher, field_value)
    elif type(value).__name__ == "Model" and hasattr(value, "saveToString"):  # a Pinocchio model
        hasher.update(b"pinocchio.Model;" + value.saveToString().encode())
    elif type(value).__name__ == "Data" and hasattr(value, "saveToString"):
        hasher.update(b"pinocchio.Data;")  # scratch space of the algorithms: not an input
    elif hasattr(value, "__dict__"):
        hasher.update(f"{type(value).__qualname__};".encode())
        _feed(hasher, {k: v for k, v in vars(value).items() if not callable(v)})
    else:
        raise TypeError(f"no digest for a {type(value).__qualname__}")


def digest(*parts: Any) -> str:
    """The digest of ``parts`` (arrays, dicts, lists, dataclasses, Pinocchio models ...) and of the code."""
    hasher = hashlib.sha256(code_digest().encode())
    for part in parts:
        _feed(hasher, part)
    return hasher.hexdigest()


class FitCache:
    """Results kept in ``directory`` by digest (:func:`digest`); None keeps nothing.

    A file is written whole or not at all (written aside, then renamed), so a round stopped midway
    leaves no half entry; an entry that cannot be read back is computed again.
    """

    def __init__(self, directory: str | Path | None) -> None:
        self.directory = Path(directory) if directory is not None else None
        self.started = time.time()

    def key(self, *parts: Any) -> str:
        """:func:`digest` of ``parts``; nothing to digest when nothing is kept."""
        return digest(*parts) if self.directory is not None else ""

    def get_or_compute(self, kind: str, key: str, compute: Callable[[], T]) -> T:
        """``compute()``, or its result of an earlier round with the same ``key`` (``kind`` names the file)."""
        found = self.get(kind, key)
        if found is not None:
            return found[0]
        value = compute()
        self.put(kind, key, value)
        return value

    def get(self, kind: str, key: str) -> tuple[Any] | None:
        """``(value,)`` kept under ``key`` by an earlier round, or None (nothing kept, or unreadable)."""
        if self.directory is None:
            return None
        path = self._path(kind, key)
        if path.exists():
            try:
                with open(path, "rb") as handle:
                    stored_key, value = pickle.load(handle)
                if stored_key == key:
                    os.utime(path)  # used by this round: not pruned
                    return (value,)
            except Exception:  # noqa: BLE001 - an unreadable entry is computed again
                pass
        return None

    def put(self, kind: str, key: str, value: Any) -> None:
        """Keep ``value`` under ``key`` (nothing when the cache keeps nothing)."""
        if self.directory is None:
            return
        path = self._path(kind, key)
        self.directory.mkdir(parents=True, exist_ok=True)
        aside = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        with open(aside, "wb") as handle:
            pickle.dump((key, value), handle, protocol=pickle.HIGHEST_PROTOCOL)
        os.replace(aside, path)

    def _path(self, kind: str, key: str) -> Path:
        assert self.directory is not None
        return self.directory / f"{kind}-{key[:40]}.pkl"

    def prune(self) -> None:
        """Remove the entries neither this round nor the round before used: the cache holds two rounds' work, so
        that undoing a round (a line removed again) costs what a round that changes nothing costs.

        A round's start is kept in :data:`ROUND_MARK` (an entry read or written is touched, so its mtime says when
        it was last used); without a readable mark (a new cache directory) only this round's entries are kept.
        """
        if self.directory is None or not self.directory.is_dir():
            return
        mark = self.directory / ROUND_MARK
        try:
            previous = float(mark.read_text())
        except (OSError, ValueError):
            previous = self.started
        cutoff = min(previous, self.started) - 1.0
        for path in [p for p in self.directory.iterdir()
                     if p.is_file() and p.name != ROUND_MARK and p.stat().st_mtime < cutoff]:
            path.unlink(missing_ok=True)
        aside = mark.with_name(f"{ROUND_MARK}.{os.getpid()}.tmp")
        aside.write_text(repr(self.started))
        os.replace(aside, mark)
