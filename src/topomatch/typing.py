"""Array type aliases used in signatures and docstrings across topomatch.

Shapes are written the same way everywhere: ``(n_vertices, 3)``, ``(n_faces, 3)``,
``(n_vertices, k)``.
"""

from __future__ import annotations

from os import PathLike
from typing import TypeAlias

import numpy as np
from numpy.typing import NDArray

FloatArray: TypeAlias = NDArray[np.float64]
IndexArray: TypeAlias = NDArray[np.int64]
BoolArray: TypeAlias = NDArray[np.bool_]
PathType: TypeAlias = str | PathLike[str]
RandomState: TypeAlias = int | np.random.Generator | None

__all__ = ["BoolArray", "FloatArray", "IndexArray", "PathType", "RandomState"]
