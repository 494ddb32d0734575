"""The run directory: manifest, maps, per-pair scores, summary. Atomic writes; resumable.

Layout::

    RUN/
      manifest.json                      configuration, versions, data checksums, timings
      maps/<method>/<pair>.npz           p2p_21, seconds, peak_rss_mb, info (one per pair)
      maps/<method>/<pair>.error.json    a pair that failed: the error, not fatal to the run
      scores/<protocol>/<geodesic>/<method>/<pair>.npz   table row + per-vertex errors
      pairs.csv                          every score row with time, memory and status
      summary.json                       per method and protocol (see ``summary``)
      report/                            tables and figures
"""

from __future__ import annotations

import csv
import io
import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from topomatch.typing import FloatArray, IndexArray

__all__ = ["RunDir"]


def _atomic_bytes(path: Path, payload: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    with open(tmp, "wb") as fh:
        fh.write(payload)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def _json_default(o: Any) -> Any:
    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.floating):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def write_json(path: Path, obj: Any) -> None:
    """Write JSON atomically (NaN written as null)."""
    text = json.dumps(_nan_to_none(obj), indent=2, default=_json_default, allow_nan=False)
    _atomic_bytes(Path(path), text.encode())


def _nan_to_none(o: Any) -> Any:
    if isinstance(o, float) and (o != o or o in (float("inf"), float("-inf"))):
        return None
    if isinstance(o, dict):
        return {k: _nan_to_none(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_nan_to_none(v) for v in o]
    return o


class RunDir:
    """Read and write one run directory."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)

    # maps -------------------------------------------------------------------------------
    def map_path(self, method: str, pair: str) -> Path:
        """Where the map of ``method`` on ``pair`` is stored."""
        return self.path / "maps" / method / f"{pair}.npz"

    def error_path(self, method: str, pair: str) -> Path:
        """Where a failure of ``method`` on ``pair`` is recorded."""
        return self.path / "maps" / method / f"{pair}.error.json"

    def save_map(self, method: str, pair: str, p2p_21: IndexArray, *, seconds: float, peak_rss_mb: float, info: dict) -> None:
        """Store a map atomically (and clear a previous failure record)."""
        buf = io.BytesIO()
        np.savez(
            buf,
            p2p_21=np.asarray(p2p_21, dtype=np.int64),
            seconds=np.float64(seconds),
            peak_rss_mb=np.float64(peak_rss_mb),
            info=np.array(json.dumps(_nan_to_none(dict(info)), default=_json_default)),
        )
        _atomic_bytes(self.map_path(method, pair), buf.getvalue())
        self.error_path(method, pair).unlink(missing_ok=True)

    def load_map(self, method: str, pair: str) -> dict[str, Any] | None:
        """The stored map record or ``None``."""
        p = self.map_path(method, pair)
        if not p.is_file():
            return None
        try:
            with np.load(p) as z:
                return {
                    "p2p_21": z["p2p_21"],
                    "seconds": float(z["seconds"]),
                    "peak_rss_mb": float(z["peak_rss_mb"]),
                    "info": json.loads(str(z["info"])),
                }
        except (OSError, ValueError, KeyError, EOFError):
            return None  # unreadable: treated as missing and recomputed

    def save_failure(self, method: str, pair: str, error: str, trace: str, seconds: float) -> None:
        """Record a failed pair."""
        write_json(self.error_path(method, pair), {"method": method, "pair": pair, "error": error, "traceback": trace, "seconds": seconds})

    def load_failure(self, method: str, pair: str) -> dict[str, Any] | None:
        """The failure record or ``None``."""
        p = self.error_path(method, pair)
        if not p.is_file():
            return None
        return json.loads(p.read_text())

    # scores -----------------------------------------------------------------------------
    def score_path(self, protocol: str, geodesic: str, method: str, pair: str) -> Path:
        """Where one score row is stored."""
        return self.path / "scores" / protocol / geodesic / method / f"{pair}.npz"

    def save_score(self, protocol: str, geodesic: str, row: dict, errors: FloatArray) -> None:
        """Store a score row and its per-vertex errors atomically."""
        buf = io.BytesIO()
        np.savez(buf, row=np.array(json.dumps(_nan_to_none(row), default=_json_default)), errors=np.asarray(errors, dtype=np.float32))
        _atomic_bytes(self.score_path(protocol, geodesic, row["method"], row["pair"]), buf.getvalue())

    def load_score(self, protocol: str, geodesic: str, method: str, pair: str, *, with_errors: bool = False) -> dict | None:
        """A stored score row (``errors`` added when asked) or ``None``."""
        p = self.score_path(protocol, geodesic, method, pair)
        if not p.is_file():
            return None
        try:
            with np.load(p) as z:
                row = json.loads(str(z["row"]))
                if with_errors:
                    row["errors"] = z["errors"]
            return row
        except (OSError, ValueError, KeyError, EOFError):
            return None

    # tables -----------------------------------------------------------------------------
    def write_pairs_csv(self, rows: list[dict]) -> None:
        """Write ``pairs.csv`` (one row per method, protocol, geodesic and pair)."""
        if not rows:
            return
        keys: list[str] = []
        for r in rows:
            keys.extend(k for k in r if k not in keys)
        buf = io.StringIO()
        w = csv.DictWriter(buf, fieldnames=keys, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if v is None else (json.dumps(v) if isinstance(v, (list, dict)) else v)) for k, v in r.items()})
        _atomic_bytes(self.path / "pairs.csv", buf.getvalue().encode())

    def manifest(self) -> dict | None:
        """The manifest, or ``None`` for a new run."""
        p = self.path / "manifest.json"
        return json.loads(p.read_text()) if p.is_file() else None

    def summary(self) -> dict | None:
        """The summary, or ``None``."""
        p = self.path / "summary.json"
        return json.loads(p.read_text()) if p.is_file() else None
