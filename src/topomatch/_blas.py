"""One BLAS thread for a block of code, cheaply (a cached ``threadpoolctl`` controller).

Some BLAS products round differently with different thread counts on some CPUs
(OpenBLAS on AMD EPYC: float32 and some float64 matrix products), so the numerics whose
bits must not depend on ``--jobs`` run on one BLAS thread. ``threadpool_limits`` scans
the loaded libraries on every call (about 0.3 ms); the controller scans them once, at
the first use, when importing ``topomatch`` has already loaded numpy's and scipy's
OpenBLAS (a BLAS library loaded only later would not be limited).
"""

from __future__ import annotations

import threading
from typing import Any

from threadpoolctl import ThreadpoolController

_controller: ThreadpoolController | None = None
_lock = threading.Lock()


def one_blas_thread() -> Any:
    """A context manager that limits the BLAS libraries to one thread."""
    global _controller
    if _controller is None:
        with _lock:
            if _controller is None:
                _controller = ThreadpoolController()
    return _controller.limit(limits=1, user_api="blas")
