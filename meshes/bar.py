"""Structured hexahedral mesh of a straight bar with a square section.

The bar is simple enough that gmsh adds nothing: dolfinx builds it directly, distributed over the
ranks. The bar spans x in [x0, x1] with its section [-a/2, a/2]² centred on the x axis.
"""

from __future__ import annotations

import dolfinx
import numpy as np
from mpi4py import MPI

from .markers import Marker

ROOT = Marker("root", 1, 2)
TIP = Marker("tip", 2, 2)


def build_bar(
    comm: MPI.Comm, x0: float, x1: float, side: float, n_axial: int, n_side: int
) -> tuple[dolfinx.mesh.Mesh, dolfinx.mesh.MeshTags]:
    """Hexahedral bar mesh and its facet tags (:data:`ROOT` at x = x0, :data:`TIP` at x = x1).

    Args:
        comm: communicator the mesh is distributed on.
        x0: axial position of the root face (m).
        x1: axial position of the tip face (m), x1 > x0.
        side: side of the square section (m).
        n_axial: number of cells along the bar.
        n_side: number of cells across each side.
    """
    if not x1 > x0:
        raise ValueError(f"bar: outer end x1 = {x1} m must exceed inner end x0 = {x0} m")
    if side <= 0 or n_axial < 1 or n_side < 1:
        raise ValueError(f"bar: side = {side} m, n_axial = {n_axial}, n_side = {n_side} invalid")
    h = side / 2
    mesh = dolfinx.mesh.create_box(
        comm,
        [np.array([x0, -h, -h]), np.array([x1, h, h])],
        [n_axial, n_side, n_side],
        cell_type=dolfinx.mesh.CellType.hexahedron,
    )
    tol = 1e-9 * (x1 - x0)
    fdim = mesh.topology.dim - 1
    root = dolfinx.mesh.locate_entities_boundary(mesh, fdim, lambda x: np.abs(x[0] - x0) < tol)
    tip = dolfinx.mesh.locate_entities_boundary(mesh, fdim, lambda x: np.abs(x[0] - x1) < tol)
    indices = np.concatenate([root, tip]).astype(np.int32)
    values = np.concatenate([np.full_like(root, ROOT.id), np.full_like(tip, TIP.id)])
    order = np.argsort(indices)
    tags = dolfinx.mesh.meshtags(mesh, fdim, indices[order], values[order].astype(np.int32))
    return mesh, tags
