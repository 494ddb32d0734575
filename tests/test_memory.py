import multiprocessing
import sys
import time

import numpy as np
import pytest

from topomatch._memory import PeakMemory, children_private_mb, current_rss_mb


def _hold(mb: int, seconds: float) -> None:
    a = np.ones(mb * 125_000)  # mb MB of float64, touched
    time.sleep(seconds)
    del a


def test_peak_memory_sees_a_block_allocation():
    with PeakMemory(interval=0.005) as pm:
        a = np.ones(25_000_000)  # 200 MB
        time.sleep(0.05)
        del a
    assert pm.peak_mb >= current_rss_mb() + 150


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="children's memory is read from Linux /proc")
def test_peak_memory_counts_a_forked_childs_private_memory():
    ctx = multiprocessing.get_context("fork")
    idle = ctx.Process(target=_hold, args=(200, 2.0))  # running before the block: not counted
    idle.start()
    time.sleep(0.5)
    others = children_private_mb()
    with PeakMemory(interval=0.005) as pm:
        p = ctx.Process(target=_hold, args=(300, 0.5))
        p.start()
        p.join()
    # the child's 300 MB count, not the pages it shares with this process
    idle.join()
    assert others >= 150  # the idle child's 200 MB were there, and not counted below
    assert current_rss_mb() + 250 <= pm.peak_mb <= current_rss_mb() + 450
