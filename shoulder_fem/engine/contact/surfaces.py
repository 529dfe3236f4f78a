"""The facets of a tagged surface, and a mesh master gathered on every rank.

Slave facets are found by the rank owning their cell (a contact then deals them to all the
ranks: :mod:`~.balance`), nodes in canonical order (v0 v1 v2 [e01 e12 e20]) and oriented
outwards. A mesh master is small: it is gathered on every rank as
flat triangles (each P1 facet, or the 4 sub-triangles of a P2 facet), its node positions
re-gathered at each evaluation. Simplices only (triangular facets of tetrahedra).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import dolfinx
import numpy as np
from mpi4py import MPI

from shoulder_fem.engine.contact.geometry import NODE_MU, P2_SUBTRIANGLES
from shoulder_fem.engine.contact.masters import ContactError

#: basix reference tetrahedron: vertices of facet f (the facet opposite vertex f).
TET_FACET_VERTICES = ((1, 2, 3), (0, 2, 3), (0, 1, 3), (0, 1, 2))
#: basix reference tetrahedron: local edge index of the edge between two vertices.
TET_EDGE = {(2, 3): 0, (1, 3): 1, (1, 2): 2, (0, 3): 3, (0, 2): 4, (0, 1): 5}


@dataclass
class Facets:
    """Canonically ordered facet nodes of a surface on this rank.

    As found by :func:`surface_facets`: the facets of this rank's owned cells, local nodes and
    CG1 dofs. A contact's slaves once dealt to the ranks (:func:`~.balance.share_slaves`): its
    nodes then also index imported nodes, and ``p1`` holds global CG1 dofs.
    """

    nodes: np.ndarray  # (nf, nn) local node (block) indices, canonical order, outward oriented
    X: np.ndarray  # (nf, nn, 3) reference coordinates of those nodes
    p1: np.ndarray  # (nf, 3) CG1 dofs of the facet vertices (pressure field)
    tags: np.ndarray  # (nf,) the facet tag value of each facet (resultants per tag)


def _tagged_facets(mesh, facet_tags, tags: Sequence[int], what: str) -> np.ndarray:
    """Local facets with any of ``tags``; every tag must exist on some rank (collective)."""
    local_known = set(np.unique(facet_tags.values).tolist())
    all_known = set().union(*mesh.comm.allgather(local_known))
    facets = []
    for t in tags:
        if t not in all_known:
            raise ContactError(
                f"{what}: facet tag {t} is not in the mesh (tags present: {sorted(all_known)})"
            )
        facets.append(facet_tags.indices[facet_tags.values == t])
    return np.unique(np.concatenate(facets)) if facets else np.zeros(0, dtype=np.int32)


def _oriented_nodes(V, Q, facets: np.ndarray, X_all: np.ndarray, degree: int):
    """Canonical, outward-oriented nodes and CG1 vertex dofs of the facets of owned cells.

    Returns:
        (nodes, p1, kept, interior): lists of node and vertex-dof lists, the positions in
        ``facets`` of the facets kept, and the number of facets that are not on the boundary.
    """
    mesh = V.mesh
    tdim = mesh.topology.dim
    f2c = mesh.topology.connectivity(tdim - 1, tdim)
    c2f = mesh.topology.connectivity(tdim, tdim - 1)
    n_owned = mesh.topology.index_map(tdim).size_local
    nodes, p1, kept = [], [], []
    interior = 0
    for k, f in enumerate(facets):
        cells = f2c.links(f)
        if len(cells) != 1:
            interior += 1
            continue
        cell = cells[0]
        if cell >= n_owned:
            continue  # handled by the rank that owns the cell
        lf = int(np.flatnonzero(c2f.links(cell) == f)[0])
        verts = TET_FACET_VERTICES[lf]
        cd = V.dofmap.cell_dofs(cell)
        order = [cd[v] for v in verts]
        if degree == 2:
            for i, j in ((0, 1), (1, 2), (2, 0)):
                a, b = sorted((verts[i], verts[j]))
                order.append(cd[4 + TET_EDGE[(a, b)]])
        # outward orientation: the normal of (v0, v1, v2) points away from the opposite vertex
        xv = X_all[order[:3]]
        apex = X_all[cd[lf]]
        nrm = np.cross(xv[1] - xv[0], xv[2] - xv[0])
        qd = Q.dofmap.cell_dofs(cell)
        pv = [qd[v] for v in verts]
        if nrm @ (xv[0] - apex) < 0:
            order = [order[0], order[2], order[1]] + (
                [order[5], order[4], order[3]] if degree == 2 else []
            )
            pv = [pv[0], pv[2], pv[1]]
        nodes.append(order)
        p1.append(pv)
        kept.append(k)
    return nodes, p1, kept, interior


def surface_facets(
    V, facet_tags, tags: Sequence[int], Q, what: str, X_all: np.ndarray | None = None
) -> Facets:
    """This rank's boundary facets with the tag values ``tags`` (collective).

    Args:
        V: Vector P1/P2 space on a tetrahedral mesh (collapsed, if a block of a mixed space).
        facet_tags: The mesh's facet tags.
        tags: Tag values of the surface.
        Q: The scalar CG1 space of the pressure fields.
        what: Names the surface in error messages.
        X_all: The reference position of every local node (default: the mesh's).

    Raises:
        ContactError: Not a tetrahedral mesh or not P1/P2, an unknown tag, a tagged facet
            inside a body, or no facet at all.
    """
    mesh = V.mesh
    tdim = mesh.topology.dim
    if mesh.topology.cell_type != dolfinx.mesh.CellType.tetrahedron:
        raise ContactError(
            f"{what}: contact needs a tetrahedral mesh, not {mesh.topology.cell_type}"
        )
    degree = V.ufl_element().degree()
    if degree not in (1, 2):
        raise ContactError(f"{what}: contact supports P1 or P2 displacement, not degree {degree}")
    mesh.topology.create_connectivity(tdim - 1, tdim)
    mesh.topology.create_connectivity(tdim, tdim - 1)
    facets = _tagged_facets(mesh, facet_tags, tags, what)
    X_mesh = V.tabulate_dof_coordinates()
    nn = 3 if degree == 1 else 6
    nodes, p1, kept, interior = _oriented_nodes(V, Q, facets, X_mesh, degree)
    interior = mesh.comm.allreduce(interior, op=MPI.SUM)
    if interior:
        raise ContactError(
            f"{what}: {interior} facets of tags {list(tags)} are inside a body, not on its surface"
        )
    nodes = np.asarray(nodes, dtype=np.int64).reshape(-1, nn)
    p1 = np.asarray(p1, dtype=np.int64).reshape(-1, 3)
    X = X_mesh[nodes] if len(nodes) else np.zeros((0, nn, 3))
    if degree == 2 and len(nodes):
        mid = 0.5 * (X[:, [0, 1, 2]] + X[:, [1, 2, 0]])
        if not np.allclose(mid, X[:, 3:], atol=1e-9 * np.ptp(X_mesh, axis=0).max()):
            raise ContactError(f"{what}: unexpected P2 edge-dof layout (mid-edge nodes not found)")
    if X_all is not None and len(nodes):
        X = X_all[nodes]
    n_local_facets = mesh.comm.allreduce(len(nodes), op=MPI.SUM)
    if n_local_facets == 0:
        raise ContactError(f"{what}: the facet tags {list(tags)} select no boundary facet")
    chosen = facets[np.asarray(kept, dtype=np.int64)]
    tags = facet_tags.values[np.searchsorted(facet_tags.indices, chosen)].astype(np.int64)
    return Facets(nodes=nodes, X=X, p1=p1, tags=tags)


@dataclass
class MasterMesh:
    """A mesh master surface gathered on every rank, as flat triangles."""

    owned_nodes: np.ndarray  # local indices of this rank's owned master nodes
    index: np.ndarray  # (nt, 3) indices into the gathered master node list
    gdofs: np.ndarray  # (nm,) global block indices of the gathered master nodes
    X: np.ndarray  # (nm, 3) reference coordinates
    boundary: np.ndarray  # (nt, 3) bool: edge k (ab, bc, ca) lies on the master's rim
    counts: list[int]  # owned master nodes per rank
    rows: np.ndarray  # (nm, 3) global rows of the gathered master nodes' components
    parent: np.ndarray | None = None  # (nt, 6) P2: the parent facet's nodes (gathered list)
    tri_mu: np.ndarray | None = None  # (nt, 3, 3) P2: the triangle's vertices in the parent
    x: np.ndarray | None = None  # (nm, 3) current positions
    x_prev: np.ndarray | None = None  # (nm, 3) positions at the last committed step
    # this rank's master facet vertices: their gathered indices and local CG1 dofs
    vertex_gathered: np.ndarray | None = None
    vertex_q: np.ndarray | None = None
    # (nm,) ∫ φ dA of each gathered vertex's linear function over the master (reference, m²)
    lumped_area: np.ndarray | None = None


def _rim_edges(index: np.ndarray, nm: int) -> np.ndarray:
    """(nt, 3) bool: the triangle edges (ab, bc, ca) used by one triangle only."""
    edges = np.sort(
        np.stack([index[:, [0, 1]], index[:, [1, 2]], index[:, [2, 0]]], axis=1), axis=2
    )
    keys = edges[..., 0] * nm + edges[..., 1]
    uniq, inv, cnt = np.unique(keys.ravel(), return_inverse=True, return_counts=True)
    return (cnt[inv] == 1).reshape(-1, 3)


def _add_p2_parents(master: MasterMesh, imap, facets: Facets, comm: MPI.Comm, order, sub):
    """P2: each flat triangle remembers its curved parent facet and its place in it."""
    nf = len(facets.nodes)
    par_local = np.concatenate([facets.nodes] * len(sub)) if nf else np.zeros((0, 6), int)
    par_global = (
        imap.local_to_global(par_local.ravel().astype(np.int32)).reshape(-1, 6)
        if nf
        else np.zeros((0, 6), dtype=np.int64)
    )
    parents = np.concatenate(comm.allgather(par_global))
    master.parent = order[np.searchsorted(master.gdofs[order], parents)]
    mu = np.concatenate([np.broadcast_to(NODE_MU[list(t)], (nf, 3, 3)) for t in sub])
    master.tri_mu = np.concatenate(comm.allgather(mu.reshape(-1, 3, 3)))


def gather_master(
    V, facets: Facets, comm: MPI.Comm, node_rows: np.ndarray, X_all: np.ndarray | None = None
) -> MasterMesh:
    """Gather a mesh master's triangles and nodes on every rank (collective).

    Args:
        V: The (collapsed) displacement space.
        facets: This rank's facets of the master surface.
        comm: The mesh's communicator.
        node_rows: Global rows (in the solved space) of the 3 components of every local node.
        X_all: The reference position of every local node (default: the mesh's).
    """
    imap = V.dofmap.index_map
    sub = [(0, 1, 2)] if facets.nodes.shape[1] == 3 else P2_SUBTRIANGLES
    tri_local = (
        np.concatenate([facets.nodes[:, list(s)] for s in sub])
        if len(facets.nodes)
        else np.zeros((0, 3), dtype=np.int64)
    )
    tri_global = (
        imap.local_to_global(tri_local.ravel().astype(np.int32)).reshape(-1, 3)
        if len(tri_local)
        else np.zeros((0, 3), dtype=np.int64)
    )
    tris = np.concatenate(comm.allgather(tri_global))
    # every rank owns its share of the master's nodes, also nodes of facets it does not hold
    # (a facet is held by the owner of its cell, its nodes may be owned by another rank)
    nodes_local = np.unique(facets.nodes).astype(np.int32)
    g_local = imap.local_to_global(nodes_local) if len(nodes_local) else np.zeros(0, dtype=np.int64)
    g_master = np.unique(np.concatenate(comm.allgather(g_local)))
    mine = np.arange(imap.size_local, dtype=np.int32)
    owned = mine[np.isin(imap.local_to_global(mine), g_master)] if len(mine) else mine
    g_owned = (
        imap.local_to_global(owned.astype(np.int32)) if len(owned) else np.zeros(0, dtype=np.int64)
    )
    X_owned = (V.tabulate_dof_coordinates() if X_all is None else X_all)[owned]
    parts_g = comm.allgather(g_owned)
    parts_X = comm.allgather(X_owned)
    rows = np.concatenate(comm.allgather(node_rows[owned])).reshape(-1, 3).astype(np.int64)
    counts = [len(p) for p in parts_g]
    gdofs = np.concatenate(parts_g).astype(np.int64)
    X = np.concatenate(parts_X).reshape(-1, 3)
    order = np.argsort(gdofs)
    pos = np.searchsorted(gdofs[order], tris)
    index = order[pos]
    if not np.array_equal(gdofs[index], tris):
        raise ContactError("master surface: a facet node is owned by no rank (mesh distribution)")
    boundary = _rim_edges(index, len(gdofs))  # rim edges: edges used by one triangle only
    master = MasterMesh(owned, index, gdofs, X, boundary, counts, rows)
    vertices = facets.nodes[:, :3].ravel().astype(np.int32)
    g_vertices = imap.local_to_global(vertices) if len(vertices) else np.zeros(0, np.int64)
    master.vertex_gathered = order[np.searchsorted(gdofs[order], g_vertices)]
    master.vertex_q = facets.p1.ravel().astype(np.int64)
    if facets.nodes.shape[1] == 6:  # P2: each flat triangle remembers its curved parent
        _add_p2_parents(master, imap, facets, comm, order, sub)
    master.lumped_area = _lumped_area(master)
    return master


def _lumped_area(m: MasterMesh) -> np.ndarray:
    """The lumped area ∫ φ_a dA (reference, m²) of each gathered master vertex.

    φ_a: the vertex's linear function on the master's flat triangles; for a P2 master, on its
    parent facets (exact from the sub-triangles' vertices).
    """
    e1 = m.X[m.index[:, 1]] - m.X[m.index[:, 0]]
    e2 = m.X[m.index[:, 2]] - m.X[m.index[:, 0]]
    area = 0.5 * np.linalg.norm(np.cross(e1, e2), axis=1)
    lumped = np.zeros(len(m.X))
    if m.parent is None:
        np.add.at(lumped, m.index, np.repeat(area[:, None] / 3.0, 3, axis=1))
    else:  # a linear function integrates to the area times its mean at the vertices
        np.add.at(lumped, m.parent[:, :3], area[:, None] * m.tri_mu.mean(axis=1))
    return lumped
