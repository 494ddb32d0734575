"""When this process may fork a helper (the background eigenbasis of ``TriangleMesh``).

A forked child starts with a copy of the parent's memory but only the forking thread.
A lock that another thread of the parent's held at the fork (in BLAS, in the memory
allocator) stays locked in the child forever, so the child could hang: the library
forks only when no other non-daemon thread is running, apart from helper threads known
to stay out of such code. A daemonic ``multiprocessing`` process may not have children
(``Process.start`` refuses with an ``AssertionError``): there too the work stays here.
"""

from __future__ import annotations

import multiprocessing
import threading

# threads that only pass work between queues and pipes, never inside BLAS or the
# allocator: joblib's (loky's) executor manager, left running after a Parallel call
SAFE_THREADS = frozenset({"ExecutorManagerThread"})


def fork_is_safe() -> bool:
    """Whether a helper process may be forked from here now.

    ``fork`` must exist on this platform, this process must not be a daemonic
    ``multiprocessing`` child, and the calling thread must be the only non-daemon
    thread running, apart from :data:`SAFE_THREADS`.
    """
    if "fork" not in multiprocessing.get_all_start_methods():
        return False
    if multiprocessing.current_process().daemon:
        return False
    me = threading.current_thread()
    return not any(t is not me and not t.daemon and t.name not in SAFE_THREADS for t in threading.enumerate())
