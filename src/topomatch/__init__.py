"""topomatch: dense correspondence between deformable shapes under topological noise.

The SHREC'16 TOPKIDS benchmark read as published, its two protocols scored exactly,
reference methods behind one Matcher interface, and the tools to run them.
"""

__version__ = "0.1.0"

from topomatch.mesh import TriangleMesh

__all__ = ["TriangleMesh", "__version__"]
