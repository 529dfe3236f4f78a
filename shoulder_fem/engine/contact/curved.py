"""Curved contact surfaces: the mid-edge nodes of a faceted P2 surface lifted onto a smooth one.

A mesh with straight-sided tetrahedra (the shoulder's, gmsh's first-order geometry) represents a
sphere of radius R by flat facets whose middles lie h^2 / (8 R) inside it (edge h). Where two
nearly conforming surfaces meet -- the cartilages of a joint -- that faceting error is of the
order of the layers' compression (at the shoulder's ``paper`` level 47 um against 15-25 um), and
the contact, not the tissue, then sets where the pressure goes: the overlaps crowd at the
facets' corners.

A P2 displacement field carries curved facets at no cost: lift each mid-edge node onto the
smooth surface through its edge's vertices and their normals. For the edge from vertex i to j
(vertex normals n_i, n_j: the facet normals averaged over the surface with Max's weights,
1 / |e1|^2 |e2|^2 for the facet's two edges at the vertex, exact for vertices on a sphere;
N. Max, J. Graphics Tools 4, 1999) the
curve through both vertices with those normals bulges from the chord at its middle by

    delta = (x_j - x_i) . (n_j - n_i) / 8,

along the mean of the two normals (to first order; exact to O(h^4 / R^3) on a sphere, where
delta = h^2 / (8 R): outwards on a convex surface, inwards on a concave one). Only the contact
sees the lifted positions (its reference coordinates: every current position is reference +
displacement, so the lift is carried along with the surface); the volume mesh is unchanged.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from mpi4py import MPI

from shoulder_fem.engine.contact.masters import MeshSurface
from shoulder_fem.engine.contact.surfaces import Facets, surface_facets

__all__ = ["lift_surfaces", "midside_lifts"]

#: The canonical P2 facet's edges (vertex i, vertex j, mid-edge node): v0 v1 v2 e01 e12 e20.
EDGES = ((0, 1, 3), (1, 2, 4), (2, 0, 5))


def lift_surfaces(V, Q, facet_tags, pairs, X: np.ndarray) -> tuple[np.ndarray, int]:
    """The reference positions ``X`` of ``V``'s local nodes with the ``curved`` pairs' lifted.

    Both surfaces of every such pair (its slave, and its master if a mesh surface), P2 only
    (collective). Returns the new positions (``X`` itself if nothing is lifted) and the number
    of mid-edge nodes lifted (all ranks).
    """
    surfaces = []
    if V.ufl_element().degree() != 2:
        return X, 0
    for p in (p for p in pairs if p.curved):
        tags = [p.slave] + ([p.master.tags] if isinstance(p.master, MeshSurface) else [])
        what = f"contact pair {p.name!r}, curved surface"
        surfaces += [surface_facets(V, facet_tags, t, Q, what) for t in tags]
    imap = V.dofmap.index_map
    l2g = imap.local_to_global(np.arange(len(X), dtype=np.int32))
    lifts = midside_lifts(surfaces, l2g, V.mesh.comm)
    if not lifts:
        return X, 0
    g = np.fromiter(lifts.keys(), dtype=np.int64)
    values = np.array(list(lifts.values()))
    order = np.argsort(g)
    pos = np.minimum(np.searchsorted(g[order], l2g), len(g) - 1)
    rows = np.flatnonzero(g[order][pos] == l2g)
    X = X.copy()
    X[rows] += values[order[pos[rows]]]
    return X, len(lifts)


def midside_lifts(
    surfaces: Sequence[Facets], l2g: np.ndarray, comm: MPI.Comm
) -> dict[int, np.ndarray]:
    """The lift of every mid-edge node of the P2 ``surfaces``, by global node (collective).

    Each surface's vertex normals are its own (two surfaces that share no facet are smoothed
    apart; a rim vertex takes the normals of the facets it has).

    Args:
        surfaces: This rank's facets of each surface (outward oriented, canonical P2 order).
        l2g: Global index of every local node.
        comm: The mesh's communicator.

    Returns:
        {global node index: lift (m, (3,))}, the same on every rank.
    """
    lifts: dict[int, np.ndarray] = {}
    for facets in surfaces:
        nodes = l2g[facets.nodes] if len(facets.nodes) else np.zeros((0, 6), dtype=np.int64)
        nodes = np.concatenate(comm.allgather(nodes.reshape(-1, 6)))
        X = np.concatenate(comm.allgather(facets.X.reshape(-1, 6, 3)))
        if len(nodes) == 0:
            continue
        # facets held twice (slaves dealt to the ranks keep one copy each): once is enough
        _, first = np.unique(np.sort(nodes[:, :3], axis=1), axis=0, return_index=True)
        nodes, X = nodes[first], X[first]
        vertices, inverse = np.unique(nodes[:, :3], return_inverse=True)
        inverse = inverse.reshape(-1, 3)
        n = np.zeros((len(vertices), 3))
        for k in range(3):  # Max's weights: exact where the vertices lie on a sphere
            e1, e2 = X[:, (k + 1) % 3] - X[:, k], X[:, (k + 2) % 3] - X[:, k]
            w = np.einsum("fi,fi->f", e1, e1) * np.einsum("fi,fi->f", e2, e2)
            np.add.at(n, inverse[:, k], np.cross(e1, e2) / w[:, None])
        n /= np.linalg.norm(n, axis=1)[:, None]
        n = _rim_normals(n, inverse, X)
        for i, j, m in EDGES:
            ni, nj = n[inverse[:, i]], n[inverse[:, j]]
            delta = np.einsum("fk,fk->f", X[:, j] - X[:, i], nj - ni) / 8.0
            direction = ni + nj
            direction /= np.linalg.norm(direction, axis=1)[:, None]
            for g, lift in zip(nodes[:, m], delta[:, None] * direction, strict=True):
                lifts[int(g)] = lift
    return lifts


def _rim_normals(n: np.ndarray, inverse: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Vertex normals ``n`` with those of the surface's rim taken from their inner neighbours.

    A rim vertex has facets on one side only, and Max's weights are then not exact. On a
    sphere the normal at x_j is the normal at a neighbour x_i reflected in the plane that
    bisects the edge, n_i - 2 (n_i . e) e (e the edge's unit vector): the rim vertex takes the
    mean of those reflections over its inner neighbours (it keeps its own without one).
    """
    edges = np.concatenate([inverse[:, [0, 1]], inverse[:, [1, 2]], inverse[:, [2, 0]]])
    corners = np.concatenate([X[:, [0, 1]], X[:, [1, 2]], X[:, [2, 0]]])
    key = np.sort(edges, axis=1)
    _, first, counts = np.unique(key, axis=0, return_index=True, return_counts=True)
    rim = np.zeros(len(n), dtype=bool)
    rim[key[first[counts == 1]].ravel()] = True
    if not rim.any():
        return n
    edges, corners = edges[first], corners[first]  # each edge once
    out = n.copy()
    total = np.zeros_like(n)
    for a, b in ((0, 1), (1, 0)):  # from inner vertex a to rim vertex b
        use = rim[edges[:, b]] & ~rim[edges[:, a]]
        e = corners[use, b] - corners[use, a]
        e /= np.linalg.norm(e, axis=1)[:, None]
        ni = n[edges[use, a]]
        np.add.at(total, edges[use, b], ni - 2.0 * np.einsum("ki,ki->k", ni, e)[:, None] * e)
    has = rim & (np.linalg.norm(total, axis=1) > 0)
    out[has] = total[has] / np.linalg.norm(total[has], axis=1)[:, None]
    return out
