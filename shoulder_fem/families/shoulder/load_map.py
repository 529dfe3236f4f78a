"""Part 1's nodal loads carried to another scapula mesh through the shared loaded surfaces.

Part 2 may run on a finer scapula than part 1 (``part2_level``): a part 1 at ``paper`` loads a
``fine`` scapula. Each transferred force, at a node of part 1's mesh on a loaded surface
(glenoid, muscle origins), is moved to the nearest point of the same surfaces of the new mesh
and shared among that triangle's three vertices by its barycentric weights. Weights are
non-negative and sum to one: the total force is kept exactly; the moment changes by the forces
times their moves (the surfaces' discretisation gap, reported as ``load_map_moment_error``).
"""

from __future__ import annotations

from dataclasses import dataclass

import dolfinx
import numpy as np
from scipy.sparse import csr_matrix
from scipy.spatial import cKDTree

from shoulder_fem.families.shoulder.geometry import entity_triangles

__all__ = ["LoadMap", "closest_on_triangles", "load_map", "surface_triangles"]

#: Candidate triangles per point (by centroid) searched for the closest one.
CANDIDATES = 16


@dataclass(frozen=True)
class LoadMap:
    """A linear map of nodal forces from ``source`` points to ``points`` (vertices).

    Attributes:
        points: The new load points, vertices of the target surfaces (m), (m, 3).
        weights: (m, n), sparse: forces at the new points = ``weights @ forces`` at the
            source points.
        moves: Per source point, the distance to its image on the target surface (m).
        source: The source points (m), (n, 3).
    """

    points: np.ndarray
    weights: csr_matrix
    moves: np.ndarray
    source: np.ndarray

    def forces(self, f: np.ndarray) -> np.ndarray:
        """The nodal forces (N, (m, 3)) at :attr:`points` equivalent to ``f`` (N, (n, 3))."""
        return np.asarray(self.weights @ f)

    def moment_error(self, f: np.ndarray, centre: np.ndarray) -> float:
        """|ΔM| / (Σ|f| × lever): the moment about ``centre`` lost by the map, relative."""
        g = self.forces(f)
        m0 = np.cross(self.source - centre, f).sum(axis=0)
        m1 = np.cross(self.points - centre, g).sum(axis=0)
        lever = float(np.linalg.norm(self.source - centre, axis=1).max()) or 1.0
        scale = float(np.linalg.norm(f, axis=1).sum()) or 1.0
        return float(np.linalg.norm(m1 - m0)) / (scale * lever)


def surface_triangles(mesh: dolfinx.mesh.Mesh, facet_tags, tags: list[int]) -> np.ndarray:
    """The vertex coordinates (m) of the facets with ``tags``, from every rank: (t, 3, 3)."""
    n_owned = mesh.topology.index_map(mesh.topology.dim - 1).size_local
    chosen = np.isin(facet_tags.values, tags) & (facet_tags.indices < n_owned)
    local = entity_triangles(mesh, facet_tags.dim, facet_tags.indices[chosen])
    return np.concatenate(mesh.comm.allgather(local))


def closest_on_triangles(p: np.ndarray, tri: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closest points to ``p`` (k, 3) on triangles ``tri`` (k, 3, 3), and barycentrics (k, 3).

    The barycentric weights are non-negative and sum to one (the point is on the triangle).
    """
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    e0, e1, d = b - a, c - a, p - a
    m00 = np.einsum("ij,ij->i", e0, e0)
    m01 = np.einsum("ij,ij->i", e0, e1)
    m11 = np.einsum("ij,ij->i", e1, e1)
    r0, r1 = np.einsum("ij,ij->i", d, e0), np.einsum("ij,ij->i", d, e1)
    det = m00 * m11 - m01**2
    s = (m11 * r0 - m01 * r1) / det
    t = (m00 * r1 - m01 * r0) / det
    lam = np.stack([1.0 - s - t, s, t], axis=1)
    inside = (lam >= 0.0).all(axis=1)
    best = np.where(inside[:, None], lam, np.nan)
    dist = np.where(inside, np.linalg.norm(p - np.einsum("ij,ijk->ik", lam, tri), axis=1), np.inf)
    for i, j in ((0, 1), (1, 2), (2, 0)):  # the closest point of each edge
        q0, q1 = tri[:, i], tri[:, j]
        edge = q1 - q0
        u = np.clip(np.einsum("ij,ij->i", p - q0, edge) / np.einsum("ij,ij->i", edge, edge), 0, 1)
        gap = np.linalg.norm(p - (q0 + u[:, None] * edge), axis=1)
        closer = gap < dist
        w = np.zeros((len(p), 3))
        w[:, i], w[:, j] = 1.0 - u, u
        best[closer], dist[closer] = w[closer], gap[closer]
    return np.einsum("ij,ijk->ik", best, tri), best


def load_map(source: np.ndarray, triangles: np.ndarray) -> LoadMap:
    """The map of nodal forces at ``source`` (n, 3) onto the vertices of ``triangles``."""
    if len(triangles) == 0:
        raise ValueError("load map: the target mesh has no loaded surface facets")
    tree = cKDTree(triangles.mean(axis=1))
    k = min(CANDIDATES, len(triangles))
    _, cand = tree.query(source, k=k)
    cand = np.asarray(cand).reshape(len(source), k)
    n = len(source)
    images, lams = closest_on_triangles(np.repeat(source, k, axis=0), triangles[cand.ravel()])
    gaps = np.linalg.norm(images - np.repeat(source, k, axis=0), axis=1).reshape(n, k)
    pick = np.argmin(gaps, axis=1)
    chosen = cand[np.arange(n), pick]
    lam = lams.reshape(n, k, 3)[np.arange(n), pick]
    verts = triangles[chosen].reshape(-1, 3)
    # the same vertex seen from several triangles: one load point (rounded to 1e-12 m)
    keys = np.round(verts / 1e-12).astype(np.int64)
    uniq, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    rows, cols = inverse.ravel(), np.repeat(np.arange(n), 3)
    weights = csr_matrix((lam.ravel(), (rows, cols)), shape=(len(uniq), n))  # duplicates add
    return LoadMap(verts[first], weights, gaps[np.arange(n), pick], np.asarray(source))
