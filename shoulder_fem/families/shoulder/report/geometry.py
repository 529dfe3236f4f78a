"""Geometry for the shoulder report: glenoid-plane coordinates, sections, point matching.

The projection that draws the glenoid maps, the cut of the scapula's tetrahedra by a horizontal
plane (Fig. 4) and the pairing of the two runs' points (the runs share their meshes).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

MATCH_TOLERANCE = 1e-9
"""Two points of the two runs are the same point if they are this close [m]."""


def glenoid_plane_coordinates(
    points: np.ndarray, centre: np.ndarray, axis: np.ndarray
) -> np.ndarray:
    """Project points onto the glenoid plane: (anterior, superior) coordinates.

    The in-plane basis is e_sup, the unit projection of +z (superior) onto the plane normal to
    ``axis`` (+y if ``axis`` is parallel to z), and e_ant = ±axis × e_sup with the sign making
    it point to +y (anterior).

    Args:
        points: (n, 3) points [m].
        centre: (3,) origin of the plane coordinates [m].
        axis: (3,) normal of the glenoid plane (any length but zero).

    Returns:
        (n, 2) array: column 0 anterior, column 1 superior [m], relative to ``centre``.

    Raises:
        ValueError: if ``axis`` is zero.
    """
    n = np.asarray(axis, dtype=float)
    norm = np.linalg.norm(n)
    if not norm > 0:
        raise ValueError(f"glenoid axis must not be zero: {axis}")
    n = n / norm

    def in_plane(v: np.ndarray) -> np.ndarray | None:
        w = v - np.dot(v, n) * n
        length = np.linalg.norm(w)
        return w / length if length > 1e-8 else None

    e_sup = in_plane(np.array([0.0, 0.0, 1.0]))
    if e_sup is None:
        e_sup = in_plane(np.array([0.0, 1.0, 0.0]))
    assert e_sup is not None
    e_ant = np.cross(n, e_sup)
    if e_ant[1] < 0 or (e_ant[1] == 0 and e_ant[0] < 0):
        e_ant = -e_ant
    d = np.asarray(points, dtype=float).reshape(-1, 3) - np.asarray(centre, dtype=float)
    return np.column_stack([d @ e_ant, d @ e_sup])


def slice_tetrahedra(
    points: np.ndarray, cells: np.ndarray, values: np.ndarray, z: float
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Cut a tetrahedral mesh with the horizontal plane ``z`` = const.

    Every tetrahedron whose vertices lie on both sides of the plane is cut (a vertex exactly on
    the plane counts as above it, so a face lying in the plane is produced once, by the
    tetrahedron below it; a plane through the lowest vertices of the mesh therefore cuts
    nothing). The cut points are on the cut edges; the nodal values are
    interpolated linearly along them. One vertex on one side gives a triangle, two on each side
    a quadrilateral (vertices in cyclic order). Polygons of zero area are dropped.

    Args:
        points: (n, 3) vertex coordinates.
        cells: (m, 4) vertex indices of the tetrahedra.
        values: (n,) nodal values.
        z: height of the plane (same unit as ``points``).

    Returns:
        ``(polygons, polygon_values)``: lists of (k, 2) arrays of the (x, y) of the cut points
        and of (k,) arrays of the interpolated values, k = 3 or 4.

    Raises:
        ValueError: on inconsistent array shapes.
    """
    points = np.asarray(points, dtype=float)
    cells = np.asarray(cells, dtype=np.int64)
    values = np.asarray(values, dtype=float)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must be (n, 3), not {points.shape}")
    if values.shape != (len(points),):
        raise ValueError(f"values must be ({len(points)},), not {values.shape}")
    if cells.size == 0:
        return [], []
    if cells.ndim != 2 or cells.shape[1] != 4:
        raise ValueError(f"cells must be (m, 4), not {cells.shape}")
    s = points[cells, 2] - float(z)
    above = s >= 0.0
    k = above.sum(axis=1)
    order = np.argsort(~above, axis=1, kind="stable")  # vertices above the plane first
    V = np.take_along_axis(cells, order, axis=1)
    S = np.take_along_axis(s, order, axis=1)

    def cut(rows: np.ndarray, edges: Sequence[tuple[int, int]]) -> tuple[np.ndarray, np.ndarray]:
        xy, f = [], []
        for i, j in edges:
            a, b = V[rows, i], V[rows, j]
            t = S[rows, i] / (S[rows, i] - S[rows, j])  # never 0/0: signs differ
            xy.append(points[a, :2] + t[:, None] * (points[b, :2] - points[a, :2]))
            f.append(values[a] + t * (values[b] - values[a]))
        return np.stack(xy, axis=1), np.stack(f, axis=1)

    pieces = [
        cut(np.flatnonzero(k == 1), ((0, 1), (0, 2), (0, 3))),
        cut(np.flatnonzero(k == 3), ((3, 0), (3, 1), (3, 2))),
        cut(np.flatnonzero(k == 2), ((0, 2), (0, 3), (1, 3), (1, 2))),
    ]
    extent = float(np.ptp(points[:, :2], axis=0).max()) if len(points) else 0.0
    tiny = 1e-14 * extent**2
    polygons: list[np.ndarray] = []
    polygon_values: list[np.ndarray] = []
    for xy, f in pieces:
        if not len(xy):
            continue
        x, y = xy[..., 0], xy[..., 1]
        area = 0.5 * np.abs(np.sum(x * np.roll(y, -1, axis=1) - np.roll(x, -1, axis=1) * y, 1))
        keep = area > tiny
        polygons.extend(xy[keep])
        polygon_values.extend(f[keep])
    return polygons, polygon_values


def match_points(
    reference: np.ndarray, other: np.ndarray, tol: float = MATCH_TOLERANCE
) -> tuple[np.ndarray, np.ndarray, float]:
    """Pair the points of two clouds that coincide (within ``tol``).

    Args:
        reference: (n, 3) points.
        other: (m, 3) points.
        tol: largest distance of a pair.

    Returns:
        ``(i_ref, i_other, fraction)``: indices of the pairs (``reference[i_ref[k]]`` is
        ``other[i_other[k]]``) and the number of pairs over max(n, m) (1 for two empty clouds).
    """
    from scipy.spatial import cKDTree

    reference = np.asarray(reference, dtype=float).reshape(-1, 3)
    other = np.asarray(other, dtype=float).reshape(-1, 3)
    n = max(len(reference), len(other))
    if n == 0:
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty, 1.0
    if len(reference) == 0 or len(other) == 0:
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty, 0.0
    if reference.shape == other.shape and np.all(np.abs(reference - other) <= tol):
        idx = np.arange(len(reference))
        return idx, idx.copy(), 1.0
    dist, j = cKDTree(other).query(reference, distance_upper_bound=tol)
    ok = np.isfinite(dist) & (dist <= tol)
    i_ref, i_other = np.flatnonzero(ok), j[ok].astype(np.int64)
    # one-to-one: a point of ``other`` paired twice counts once
    i_other, first = np.unique(i_other, return_index=True)
    i_ref = i_ref[first]
    order = np.argsort(i_ref)
    return i_ref[order], i_other[order], len(i_ref) / n
