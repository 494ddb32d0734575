"""Reading and writing meshes and correspondence files.

Indices are one-based on disk and zero-based in memory; the conversion happens here
and nowhere else.
"""

from topomatch.io.correspondences import (
    read_indmap,
    read_p2p,
    read_ref,
    read_shrec16_map,
    read_sym,
    read_vts,
    write_indmap,
    write_p2p,
    write_ref,
    write_shrec16_map,
    write_sym,
    write_vts,
)
from topomatch.io.meshes import (
    read_mesh,
    read_obj,
    read_off,
    read_ply,
    write_mesh,
    write_obj,
    write_off,
    write_ply,
)

__all__ = [
    "read_indmap",
    "read_mesh",
    "read_obj",
    "read_off",
    "read_p2p",
    "read_ply",
    "read_ref",
    "read_shrec16_map",
    "read_sym",
    "read_vts",
    "write_indmap",
    "write_mesh",
    "write_obj",
    "write_off",
    "write_p2p",
    "write_ply",
    "write_ref",
    "write_shrec16_map",
    "write_sym",
    "write_vts",
]
