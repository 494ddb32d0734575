"""Content-addressed disk cache for expensive per-mesh arrays (eigenbases).

The cache is off unless a directory is configured, by ``TOPOMATCH_CACHE_DIR`` or by
:func:`set_cache_dir` (the command line turns it on). Keys hash the array contents
and the parameters, never file names. Writes are atomic; a corrupt entry is ignored
and recomputed.
"""

from __future__ import annotations

import hashlib
import logging
import os
from pathlib import Path

import numpy as np

logger = logging.getLogger(__name__)

_CACHE_DIR: Path | None = None
CACHE_VERSION = "1"


def set_cache_dir(path: str | os.PathLike[str] | None) -> None:
    """Enable the disk cache in ``path`` (``None`` falls back to ``TOPOMATCH_CACHE_DIR``)."""
    global _CACHE_DIR
    _CACHE_DIR = Path(path) if path is not None else None
    if path is not None:
        os.environ["TOPOMATCH_CACHE_DIR"] = str(path)  # picked up by worker processes


def cache_dir() -> Path | None:
    """The active cache directory, or ``None`` when caching is off."""
    if _CACHE_DIR is not None:
        return _CACHE_DIR
    env = os.environ.get("TOPOMATCH_CACHE_DIR")
    return Path(env) if env else None


def default_cache_dir() -> Path:
    """Where the command line caches by default (``$XDG_CACHE_HOME/topomatch``)."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "topomatch"


def array_hash(*arrays: np.ndarray, extra: str = "") -> str:
    """SHA-256 of array dtypes, shapes and bytes plus an extra string."""
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(str(a.dtype).encode())
        h.update(str(a.shape).encode())
        h.update(a.tobytes())
    h.update(extra.encode())
    h.update(CACHE_VERSION.encode())
    return h.hexdigest()


def exists(kind: str, key: str) -> bool:
    """Whether an entry is stored (``False`` when caching is off)."""
    d = cache_dir()
    return d is not None and (d / kind / f"{key}.npz").is_file()


def load(kind: str, key: str) -> dict[str, np.ndarray] | None:
    """Load a cached entry or return ``None``."""
    d = cache_dir()
    if d is None:
        return None
    path = d / kind / f"{key}.npz"
    if not path.is_file():
        return None
    try:
        with np.load(path) as z:
            return {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError) as err:
        logger.warning("ignoring unreadable cache entry %s (%s)", path, err)
        return None


def save(kind: str, key: str, arrays: dict[str, np.ndarray]) -> None:
    """Store an entry atomically (no-op when caching is off)."""
    d = cache_dir()
    if d is None:
        return
    folder = d / kind
    try:
        folder.mkdir(parents=True, exist_ok=True)
        tmp = folder / f".{key}.{os.getpid()}.tmp.npz"
        np.savez(tmp, **arrays)
        os.replace(tmp, folder / f"{key}.npz")
    except OSError as err:
        logger.warning("could not write cache entry in %s (%s)", folder, err)
