"""Structured hexahedral mesh of a rectangular box centred on the origin.

The box is simple enough that gmsh adds nothing: dolfinx builds it directly, distributed over the
ranks. It spans ``[-a/2, a/2] × [-b/2, b/2] × [-c/2, c/2]`` for side lengths ``(a, b, c)`` in m,
so its centre of mass (uniform density) is the origin and its principal axes are x, y, z.
A free body has no boundary conditions, so no facet tags are made.
"""

from __future__ import annotations

import dolfinx
import numpy as np
from mpi4py import MPI


def build_box(
    comm: MPI.Comm, lengths: tuple[float, float, float], cells: tuple[int, int, int]
) -> dolfinx.mesh.Mesh:
    """Hexahedral mesh of a box centred on the origin.

    Args:
        comm: communicator the mesh is distributed on.
        lengths: side lengths (a, b, c) along x, y, z (m), each > 0.
        cells: number of cells along x, y, z, each >= 1.

    Returns:
        The dolfinx mesh (hexahedra).

    Raises:
        ValueError: a non-positive length or cell count.
    """
    a = np.asarray(lengths, dtype=float)
    n = [int(k) for k in cells]
    if a.shape != (3,) or np.any(~(a > 0)) or len(n) != 3 or min(n) < 1:
        raise ValueError(f"box: lengths = {lengths} m and cells = {cells} must be positive")
    return dolfinx.mesh.create_box(
        comm, [-a / 2, a / 2], n, cell_type=dolfinx.mesh.CellType.hexahedron
    )
