"""Peak resident memory of the current process during a block of code (Linux /proc, else rusage).

Child processes started during the block count with their private memory (what they
add beyond the pages they share with this process after a fork): a matcher that forks a
helper (the ``deform`` matcher's background eigenbasis) is charged for it; children that
were already running (an idle worker pool) are not.
"""

from __future__ import annotations

import glob
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


def child_pids() -> set[int]:
    """Process ids of this process's children (empty where ``/proc`` does not list them)."""
    pids: set[int] = set()
    for path in glob.glob("/proc/self/task/*/children"):
        try:
            with open(path) as fh:
                pids.update(int(p) for p in fh.read().split())
        except (OSError, ValueError):
            continue
    return pids


def children_private_mb(exclude: frozenset[int] = frozenset()) -> float:
    """Private memory (``Private_Clean + Private_Dirty``) of this process's children, in MB (0 when unknown).

    Children whose ids are in ``exclude`` are left out.
    """
    total = 0
    for pid in child_pids() - exclude:
        try:
            with open(f"/proc/{pid}/smaps_rollup") as fh:
                for line in fh:
                    if line.startswith(("Private_Clean:", "Private_Dirty:")):
                        total += int(line.split()[1])  # kB
        except (OSError, ValueError, IndexError):
            continue  # the child ended meanwhile
    return total / 1e3


def max_rss_mb() -> float:
    """Peak RSS of the process so far, in MB."""
    r = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return r / 1e6 if sys.platform == "darwin" else r / 1e3


CHILD_INTERVAL = 0.1


class PeakMemory:
    """Context manager sampling RSS (with children's private memory) every ``interval`` seconds; ``peak_mb`` after exit."""

    def __init__(self, interval: float = 0.01) -> None:
        self.interval = interval
        self.peak_mb = float("nan")
        self._stop = threading.Event()

    def __enter__(self) -> PeakMemory:
        self.peak_mb = current_rss_mb()
        self._before = frozenset(child_pids())  # e.g. idle worker pools: not the block's
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        return self

    def _run(self) -> None:
        # children are read every CHILD_INTERVAL seconds: their smaps_rollup costs about
        # 5 ms for a 500 MB process, too much to read every 10 ms beside the work measured
        every = max(1, round(CHILD_INTERVAL / self.interval))
        i, children = 0, 0.0
        while not self._stop.is_set():
            if i % every == 0:
                children = children_private_mb(exclude=self._before)
            i += 1
            r = current_rss_mb() + children
            if r > self.peak_mb or self.peak_mb != self.peak_mb:
                self.peak_mb = r
            time.sleep(self.interval)

    def __exit__(self, exc_type: type | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        self._stop.set()
        self._thread.join()
        r = current_rss_mb()
        if r > self.peak_mb:
            self.peak_mb = r
