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

from shoulder_fem.engine.contact import closest_points_on_triangles
from shoulder_fem.families.shoulder.geometry import entity_triangles

__all__ = ["LoadMap", "load_map", "surface_triangles"]

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


def load_map(source: np.ndarray, triangles: np.ndarray) -> LoadMap:
    """The map of nodal forces at ``source`` (n, 3) onto the vertices of ``triangles``."""
    if len(triangles) == 0:
        raise ValueError("load map: the target mesh has no loaded surface facets")
    tree = cKDTree(triangles.mean(axis=1))
    k = min(CANDIDATES, len(triangles))
    _, cand = tree.query(source, k=k)
    cand = np.asarray(cand).reshape(len(source), k)
    n = len(source)
    tri = triangles[cand]  # (n, k, 3, 3)
    _, lams, dist2, _ = closest_points_on_triangles(
        source[:, None, :], tri[..., 0, :], tri[..., 1, :], tri[..., 2, :]
    )
    pick = np.argmin(dist2, axis=1)
    chosen = cand[np.arange(n), pick]
    lam = lams[np.arange(n), pick]
    gaps = np.sqrt(dist2[np.arange(n), pick])
    verts = triangles[chosen].reshape(-1, 3)
    # the same vertex seen from several triangles: one load point (rounded to 1e-12 m)
    keys = np.round(verts / 1e-12).astype(np.int64)
    uniq, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    rows, cols = inverse.ravel(), np.repeat(np.arange(n), 3)
    weights = csr_matrix((lam.ravel(), (rows, cols)), shape=(len(uniq), n))  # duplicates add
    return LoadMap(verts[first], weights, gaps, np.asarray(source))
