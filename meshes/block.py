"""Structured hexahedral mesh of a slender square-section block, optionally capped by a plate.

The block spans z in [0, L] with its section [-a/2, a/2]² centred on the z axis; an optional
plate layer of thickness h spans z in [L, L + h]. dolfinx builds the box directly (no gmsh:
nothing curved), distributed over the ranks, and the z coordinates are then mapped piecewise so
that the block's cells have height L/n_axial and the plate's h/n_plate.
"""

from __future__ import annotations

import dolfinx
import numpy as np
from mpi4py import MPI

from .markers import Marker

BLOCK = Marker("block", 1, 3)
PLATE = Marker("plate", 2, 3)
BASE = Marker("base", 1, 2)
TOP = Marker("top", 2, 2)
PLATE_TOP = Marker("plate_top", 3, 2)


def build_block(
    comm: MPI.Comm,
    side: float,
    length: float,
    n_side: int,
    n_axial: int,
    plate_thickness: float = 0.0,
    n_plate: int = 0,
) -> tuple[dolfinx.mesh.Mesh, dolfinx.mesh.MeshTags, dolfinx.mesh.MeshTags]:
    """Hexahedral block mesh with cell tags and facet tags.

    Args:
        comm: Communicator the mesh is distributed on.
        side: Side a of the square section (m).
        length: Length L of the block along z (m).
        n_side: Cells across each side.
        n_axial: Cells along the block.
        plate_thickness: Thickness h of the plate layer on top (m); 0 for none.
        n_plate: Cells through the plate's thickness (>= 1 when h > 0).

    Returns:
        ``(mesh, cell_tags, facet_tags)``: cells :data:`BLOCK` / :data:`PLATE`; facets
        :data:`BASE` (z = 0), :data:`TOP` (z = L, the block's top face; interior when there is
        a plate) and :data:`PLATE_TOP` (z = L + h).
    """
    if side <= 0 or length <= 0 or n_side < 1 or n_axial < 1:
        raise ValueError(
            f"block: side = {side} m, length = {length} m, n_side = {n_side}, "
            f"n_axial = {n_axial} invalid"
        )
    with_plate = plate_thickness > 0
    if with_plate and n_plate < 1:
        raise ValueError(f"block: plate of {plate_thickness} m needs n_plate >= 1")
    n_z = n_axial + (n_plate if with_plate else 0)
    h = side / 2
    mesh = dolfinx.mesh.create_box(
        comm,
        [np.array([-h, -h, 0.0]), np.array([h, h, float(n_z)])],
        [n_side, n_side, n_z],
        cell_type=dolfinx.mesh.CellType.hexahedron,
    )
    x = mesh.geometry.x
    zeta = x[:, 2].copy()  # cell-layer coordinate
    in_block = zeta <= n_axial + 1e-9
    x[in_block, 2] = zeta[in_block] * length / n_axial
    if with_plate:
        x[~in_block, 2] = length + (zeta[~in_block] - n_axial) * plate_thickness / n_plate
    tol = 1e-9 * length
    top_z = length + (plate_thickness if with_plate else 0.0)
    tdim = mesh.topology.dim
    mesh.topology.create_connectivity(tdim - 1, tdim)
    base = dolfinx.mesh.locate_entities(mesh, tdim - 1, lambda p: np.abs(p[2]) < tol)
    top = dolfinx.mesh.locate_entities(mesh, tdim - 1, lambda p: np.abs(p[2] - length) < tol)
    parts = [(base, BASE.id), (top, TOP.id)]
    if with_plate:
        cap = dolfinx.mesh.locate_entities(mesh, tdim - 1, lambda p: np.abs(p[2] - top_z) < tol)
        parts.append((cap, PLATE_TOP.id))
    facet_tags = _tags(mesh, tdim - 1, parts)
    plate_cells = dolfinx.mesh.locate_entities(mesh, tdim, lambda p: p[2] > length - tol)
    n_cells = mesh.topology.index_map(tdim).size_local + mesh.topology.index_map(tdim).num_ghosts
    block_cells = np.setdiff1d(np.arange(n_cells, dtype=np.int32), plate_cells)
    cell_tags = _tags(mesh, tdim, [(block_cells, BLOCK.id), (plate_cells, PLATE.id)])
    return mesh, cell_tags, facet_tags


def _tags(mesh: dolfinx.mesh.Mesh, dim: int, parts: list) -> dolfinx.mesh.MeshTags:
    indices = np.concatenate([p[0] for p in parts]).astype(np.int32)
    values = np.concatenate([np.full(len(p[0]), p[1], dtype=np.int32) for p in parts])
    order = np.argsort(indices)
    return dolfinx.mesh.meshtags(mesh, dim, indices[order], values[order])
