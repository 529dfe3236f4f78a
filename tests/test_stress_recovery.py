"""Nodal stress recovery (engine.stress_recovery) against computations by hand."""

from __future__ import annotations

import dolfinx
import numpy as np
import pytest
import ufl
from mpi4py import MPI
from scipy.spatial import cKDTree

from shoulder_fem.engine.stress_recovery import NodalStress, von_mises_of

pytestmark = pytest.mark.mpi


def _cube(n=3):
    return dolfinx.mesh.create_box(
        MPI.COMM_WORLD,
        [[0.0, 0.0, 0.0], [1.0, 0.8, 0.6]],
        [n, n, n],
        dolfinx.mesh.CellType.tetrahedron,
    )


def _field(x):
    """A stress that is quadratic in space, with shear (Pa), and the same in numpy."""
    return ufl.as_matrix(
        [
            [3.0 + x[0] ** 2, x[1] * x[2], 0.5],
            [x[1] * x[2], -1.0 + 2 * x[1], x[0] * x[1]],
            [0.5, x[0] * x[1], x[2] ** 2 - x[0]],
        ]
    )


def _field_np(p):
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    one = np.ones_like(x)
    rows = [
        [3.0 + x**2, y * z, 0.5 * one],
        [y * z, -1.0 + 2 * y, x * y],
        [0.5 * one, x * y, z**2 - x],
    ]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


def _gathered(mesh, rec):
    """Every rank: the owned cells' vertex coordinates, and the body's nodes with their
    recovered von Mises stress and tensor, all gathered."""
    comm = mesh.comm
    x = mesh.geometry.x
    geo = mesh.geometry.dofmap
    cells = np.array([x[geo.links(c)] for c in rec.cells]).reshape(-1, 4, 3)
    X = rec.P.tabulate_dof_coordinates()[rec.nodes]
    vm = rec.von_mises.x.array[rec.nodes]
    tens = rec.tensor.x.array.reshape(-1, 9)[rec.nodes]
    cat = lambda a: np.concatenate(comm.allgather(a))  # noqa: E731
    return cat(cells), cat(X), cat(vm), cat(tens)


def _cells_at(cells, X):
    """For each node X, the cells having it as a vertex, and which vertex."""
    tree = cKDTree(cells.reshape(-1, 3))
    out = []
    for p in X:
        hits = tree.query_ball_point(p, 1e-9)
        out.append([(h // 4, h % 4) for h in hits])
    return out


def test_tensor_recipe_is_the_mean_of_linear_fits_through_the_gauss_points():
    """The tensor recipe by hand: in each cell, the linear function through the stress at
    the 4 Gauss points of the degree-2 rule (found here in physical coordinates, by a 4 x 4
    solve per cell and component) taken at the node, the plain mean over the node's cells,
    then von Mises. Equal to round-off; serial = 2 ranks (gathered, by coordinates)."""
    mesh = _cube()
    tdim = mesh.topology.dim
    cells = np.arange(
        mesh.topology.index_map(tdim).size_local + mesh.topology.index_map(tdim).num_ghosts
    )
    rec = NodalStress(mesh, cells, _field(ufl.SpatialCoordinate(mesh)))
    rec.update()
    vcells, X, vm, tens = _gathered(mesh, rec)
    # the degree-2 Gauss points: barycentric (a, b, b, b), a = (5 + 3 sqrt 5) / 20
    a = (5 + 3 * np.sqrt(5)) / 20
    b = (5 - np.sqrt(5)) / 20
    bary = np.full((4, 4), b) + np.eye(4) * (a - b)
    expected = []
    for p, around in zip(X, _cells_at(vcells, X), strict=True):
        acc = np.zeros((3, 3))
        for c, _ in around:
            gp = bary @ vcells[c]  # (4 points, 3)
            A = np.column_stack([np.ones(4), gp])
            coef = np.linalg.solve(A, _field_np(gp).reshape(4, 9))
            acc += (np.r_[1.0, p] @ coef).reshape(3, 3)
        expected.append(acc / len(around))
    expected = np.array(expected)
    assert len(X) == mesh.topology.index_map(0).size_global
    assert np.allclose(tens.reshape(-1, 3, 3), expected, rtol=0, atol=1e-12)
    assert np.allclose(vm, von_mises_of(expected), rtol=0, atol=1e-12)
    # a linear field is recovered exactly at every node (extrapolation and mean are exact)
    x = ufl.SpatialCoordinate(mesh)
    lin = NodalStress(
        mesh, cells, ufl.as_matrix([[x[0], 2 * x[1], 0], [2 * x[1], x[2], 1], [0, 1, -x[0]]])
    )
    lin.update()
    _, X, vm, _ = _gathered(mesh, lin)
    xx, y, z = X.T
    zero = np.zeros_like(xx)
    exact = np.stack(
        [
            np.stack([xx, 2 * y, zero], -1),
            np.stack([2 * y, z, zero + 1], -1),
            np.stack([zero, zero + 1, -xx], -1),
        ],
        axis=-2,
    )
    assert np.allclose(vm, von_mises_of(exact), rtol=0, atol=1e-12)


def test_scalar_recipe_is_the_volume_weighted_mean_of_vertex_von_mises():
    """The earlier recipe by hand: each cell's von Mises stress of the field at the node,
    weighted by the cell volumes, on a body of half the cube (the other half's cells add
    nothing to its nodes on the interface); serial = 2 ranks."""
    mesh = _cube()
    x = ufl.SpatialCoordinate(mesh)
    mid = dolfinx.mesh.locate_entities(mesh, 3, lambda p: p[0] <= 0.5 + 1e-12)
    scalar = NodalStress(mesh, mid, _field(x), recipe="scalar")
    scalar.update()
    vcells, X, vm, _ = _gathered(mesh, scalar)
    assert np.all(vcells[:, :, 0] <= 0.5 + 1e-12) and len(vcells)
    expected = []
    for p, around in zip(X, _cells_at(vcells, X), strict=True):
        vol = np.array([abs(np.linalg.det(vcells[c][1:] - vcells[c][0])) / 6 for c, _ in around])
        val = np.array([von_mises_of(_field_np(p)) for _ in around])
        expected.append(np.dot(vol, val) / vol.sum())
    assert np.allclose(vm, expected, rtol=1e-12, atol=0)


def test_bad_recipe_is_refused():
    mesh = _cube(1)
    with pytest.raises(ValueError, match="recipe 'nodal'"):
        NodalStress(mesh, np.arange(2), ufl.Identity(3), recipe="nodal")
