"""Geometric measures of the shoulder meshes: surface centroids, joint frames, rotation angles.

Pure geometry on the meshes of :mod:`shoulder_fem.meshes.shoulder` and on rotation matrices
(no forms, no solver): where the springs and plates attach, the glenoid's and the humeral
cartilage's frames, and the humerus's twist and swing about its shaft, shared by both methods.
"""

from __future__ import annotations

import math

import dolfinx
import numpy as np
from mpi4py import MPI
from scipy.spatial.transform import Rotation

from shoulder_fem.meshes import shoulder as S

__all__ = [
    "best_fit_rotation",
    "best_fit_twist",
    "best_rigid_fit",
    "cap_angles",
    "entity_triangles",
    "gather_rows",
    "glenoid_frame",
    "humeral_cap",
    "marker_names",
    "patch_centroid",
    "surface_centroid",
    "swing_angle",
    "twist_angle",
    "twist_gradient",
    "unit",
]


def entity_triangles(mesh, dim: int, entities: np.ndarray) -> np.ndarray:
    """Vertex coordinates (m) of straight triangles (facets or 2D cells): (n, 3, 3)."""
    tdim = mesh.topology.dim
    mesh.topology.create_connectivity(dim, 0)
    mesh.topology.create_connectivity(tdim, 0)
    conn = mesh.topology.connectivity(dim, 0)
    c_to_v = mesh.topology.connectivity(tdim, 0)
    n_vert = mesh.topology.index_map(0).size_local + mesh.topology.index_map(0).num_ghosts
    # vertex -> geometry node (straight P1 geometry: the cells' vertex and node lists agree)
    v_to_x = np.zeros(n_vert, dtype=np.int64)
    v_to_x[c_to_v.array] = mesh.geometry.dofmap.array
    if len(entities) == 0:
        return np.zeros((0, 3, 3))
    tri = np.vstack([conn.links(e) for e in entities]).astype(np.int64)
    return mesh.geometry.x[v_to_x[tri]]


def _entity_centroids(mesh, dim: int, entities: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centroids (m) and areas (m^2) of straight triangles (facets or 2D cells)."""
    p = entity_triangles(mesh, dim, entities)
    area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    return p.mean(axis=1), area


def patch_centroid(mesh, tags, tag) -> np.ndarray:
    """Area-weighted centroid (m) of the entities of ``tags`` with value(s) ``tag`` (collective).

    ``tag``: one value or a list of them (a surface made of several markers).
    """
    dim = tags.dim
    n_owned = mesh.topology.index_map(dim).size_local
    chosen = np.isin(tags.values, np.atleast_1d(tag)) & (tags.indices < n_owned)
    ents = tags.indices[chosen]
    local = np.zeros(4)
    if len(ents):
        c, a = _entity_centroids(mesh, dim, ents)
        local[:3] = (c * a[:, None]).sum(axis=0)
        local[3] = a.sum()
    total = mesh.comm.allreduce(local, op=MPI.SUM)
    if total[3] <= 0:
        raise ValueError(f"shoulder mesh: surface tag {tag} is empty")
    return total[:3] / total[3]


def marker_names(surface: str) -> tuple[str, ...]:
    """The markers of a surface: a set of :data:`meshes.shoulder.SURFACE_SETS` or one marker."""
    return S.SURFACE_SETS.get(surface, (surface,))


def surface_centroid(mesh, tags, surface: str) -> np.ndarray:
    """Area-weighted centroid (m) of a marker or a marker set (collective)."""
    return patch_centroid(mesh, tags, [S.MARKERS[n].id for n in marker_names(surface)])


def twist_angle(R: np.ndarray, axis: np.ndarray) -> float:
    """Twist (rad) of rotation ``R`` about the unit ``axis`` (swing-twist decomposition)."""
    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return 2.0 * math.atan2(float(np.dot([x, y, z], axis)), w)


def swing_angle(R: np.ndarray, axis: np.ndarray) -> float:
    """Swing (rad) of rotation ``R``: the angle by which it turns the unit ``axis`` itself."""
    return math.acos(float(np.clip(np.dot(axis, R @ axis), -1.0, 1.0)))


def swing_parts(R: np.ndarray, axis: np.ndarray) -> tuple[float, float]:
    """The swing of the shaft under ``R`` (rad) as a change of elevation and of azimuth.

    The frame is the shoulder's (x lateral, y anterior, z up) and ``axis`` points up the shaft
    (:attr:`ShoulderModel.shaft_axis`). Elevation: the change of the shaft's angle from the
    downward vertical (positive: raised, as in abduction; what the vertical distal elements
    resist). Azimuth: the change of the shaft's horizontal direction about the vertical
    (positive: its distal end turns from lateral towards anterior; a horizontal swing, which
    vertical elements do not resist).
    """
    a, b = -np.asarray(axis, dtype=float), -(np.asarray(R, dtype=float) @ axis)  # distal

    def elevation(d: np.ndarray) -> float:
        return math.acos(float(np.clip(-d[2] / np.linalg.norm(d), -1.0, 1.0)))

    turn = math.atan2(float(b[1]), float(b[0])) - math.atan2(float(a[1]), float(a[0]))
    return elevation(b) - elevation(a), math.remainder(turn, 2.0 * math.pi)


def cap_angles(X: np.ndarray, centre: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Angles (rad) of points ``X`` (n, 3) from the unit ``axis`` of a cap, seen from ``centre``."""
    d = np.asarray(X, dtype=float).reshape(-1, 3) - centre
    r = np.linalg.norm(d, axis=1)
    return np.arccos(np.clip(d @ axis / np.where(r > 0, r, 1.0), -1.0, 1.0))


def best_rigid_fit(X: np.ndarray, x: np.ndarray, comm: MPI.Comm) -> tuple[np.ndarray, ...]:
    """The least-squares rigid fit ``x ~ c + R (X - C)`` over the owned points (collective).

    Returns:
        (C, c, R): the centroids (m) of X and x, and the rotation (Kabsch).
    """
    n = comm.allreduce(len(X), op=MPI.SUM)
    C = comm.allreduce(X.sum(axis=0), op=MPI.SUM) / n
    c = comm.allreduce(x.sum(axis=0), op=MPI.SUM) / n
    H = comm.allreduce((X - C).T @ (x - c), op=MPI.SUM)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    return C, c, Vt.T @ np.diag([1.0, 1.0, d]) @ U.T


def best_fit_rotation(X: np.ndarray, x: np.ndarray, comm: MPI.Comm) -> np.ndarray:
    """Rotation of the least-squares rigid fit x ~ c + R (X - C) over the owned points (Kabsch)."""
    return best_rigid_fit(X, x, comm)[2]


def twist_gradient(R: np.ndarray, axis: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """The derivative of twist_angle by ω (1/rad), ``R → exp(hat ω) R``: central differences."""
    grad = np.zeros(3)
    for j in range(3):
        step = Rotation.from_rotvec(h * np.eye(3)[j]).as_matrix()
        plus, minus = twist_angle(step @ R, axis), twist_angle(step.T @ R, axis)
        grad[j] = (plus - minus) / (2.0 * h)
    return grad


def best_fit_twist(
    X: np.ndarray, x: np.ndarray, axis: np.ndarray, comm: MPI.Comm, with_gradient: bool
) -> tuple[float, np.ndarray | None]:
    """Twist (rad) of the best-fit rotation of points ``X`` -> ``x``, and its gradient (collective).

    The gradient (n, 3) with respect to the owned points ``x`` linearises the fit: with
    Y_i = R (X_i - C) and y_i = x_i - c, the optimal R makes Σ Y_i × y_i vanish; perturbed by
    δx and R → exp(hat ω) R this gives M ω = -Σ Y_i × δx_i with M = Σ Y_i y_iᵀ - (Σ Y_i·y_i) I
    (the mean δx drops out as Σ Y_i = 0). So d twist / d x_i = Y_i × s with s = M⁻ᵀ dtwist/dω.
    """
    C, c, R = best_rigid_fit(X, x, comm)
    value = twist_angle(R, axis)
    if not with_gradient:
        return value, None
    Y, y = (X - C) @ R.T, x - c
    H = comm.allreduce(Y.T @ y, op=MPI.SUM)
    M = H - np.trace(H) * np.eye(3)
    s = np.linalg.solve(M.T, twist_gradient(R, axis))
    return value, np.cross(Y, s)


def unit(v) -> np.ndarray:
    """``v`` divided by its norm (a unit vector, float)."""
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def gather_rows(a: np.ndarray, comm: MPI.Comm) -> np.ndarray:
    """The rows of ``a`` of every rank, in rank order, on every rank (collective)."""
    parts = comm.allgather(np.asarray(a))
    return np.concatenate(parts, axis=0) if parts else np.asarray(a)


def humeral_cap(mesh, ft) -> tuple[np.ndarray, np.ndarray, float]:
    """The humeral cartilage as meshed: centre (m), unit axis, half-angle (rad) (collective).

    The centre is the articular sphere's (the frame origin of :mod:`meshes.shoulder`, for every
    head shape); the axis points from it to the centroid of the articular surface; the
    half-angle is that of the articular surface's farthest node from the axis.
    """
    centre = np.zeros(3)
    axis = unit(patch_centroid(mesh, ft, S.MARKERS["humeral_articular"].id) - centre)
    Q = dolfinx.fem.FunctionSpace(mesh, ("Lagrange", 1))
    nodes = dolfinx.fem.locate_dofs_topological(Q, 2, ft.find(S.MARKERS["humeral_articular"].id))
    X = Q.tabulate_dof_coordinates()[nodes]
    half = float(cap_angles(X, centre, axis).max(initial=0.0))
    return centre, axis, mesh.comm.allreduce(half, op=MPI.MAX)


def glenoid_frame(mesh, ft) -> tuple[np.ndarray, np.ndarray]:
    """Centre (m) and outward unit axis of the glenoid articular surface (collective)."""
    centre = patch_centroid(mesh, ft, S.MARKERS["glenoid_articular"].id)
    bone = patch_centroid(mesh, ft, S.MARKERS["glenoid_cartilage_bone"].id)
    return centre, unit(centre - bone)
