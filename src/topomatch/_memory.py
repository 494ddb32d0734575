"""Peak resident memory of the current process during a block of code (Linux /proc, else rusage)."""

from __future__ import annotations

import resource
import sys
import threading
import time
from types import TracebackType


def current_rss_mb() -> float:
    """Resident set size now, in MB (``nan`` when unknown)."""
    try:
        with open("/proc/self/statm") as fh:
            pages = int(fh.read().split()[1])
        return pages * resource.getpagesize() / 1e6
    except (OSError, ValueError, IndexError):
        return float("nan")


def max_rss_mb() -> float:
    """Peak RSS of the process so far, in MB."""
    r = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return r / 1e6 if sys.platform == "darwin" else r / 1e3


class PeakMemory:
    """Context manager sampling RSS every ``interval`` seconds; ``peak_mb`` after exit."""

    def __init__(self, interval: float = 0.01) -> None:
        self.interval = interval
        self.peak_mb = float("nan")
        self._stop = threading.Event()

    def __enter__(self) -> PeakMemory:
        self.peak_mb = current_rss_mb()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        return self

    def _run(self) -> None:
        while not self._stop.is_set():
            r = current_rss_mb()
            if r > self.peak_mb or self.peak_mb != self.peak_mb:
                self.peak_mb = r
            time.sleep(self.interval)

    def __exit__(self, exc_type: type | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        self._stop.set()
        self._thread.join()
        r = current_rss_mb()
        if r > self.peak_mb:
            self.peak_mb = r
