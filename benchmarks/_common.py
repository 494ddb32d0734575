"""Small helpers shared by the benchmark scripts (run as ``python benchmarks/<script>.py``)."""

from __future__ import annotations

import json


def emit_row(row: dict, path: str | None) -> None:
    """Print ``row`` as one JSON line and, when ``path`` is given, append it there."""
    line = json.dumps(row)
    print(line, flush=True)
    if path:
        with open(path, "a") as fh:
            fh.write(line + "\n")
