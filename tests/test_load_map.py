"""Part 1's nodal loads carried to another scapula mesh (families/shoulder/load_map.py)."""

from __future__ import annotations

import dolfinx
import numpy as np
import pytest
from mpi4py import MPI

from shoulder_fem import load_scene, run
from shoulder_fem.engine.contact import closest_points_on_triangles
from shoulder_fem.families.shoulder.load_map import load_map
from shoulder_fem.families.shoulder.model import build, check_bench
from shoulder_fem.scene import SceneError

TRI = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def test_closest_point_on_a_triangle_by_hand():
    """Above the interior: the foot of the normal, barycentrics (1 - s - t, s, t); beyond
    the hypotenuse: its midpoint; beyond a corner: the corner."""
    p = np.array([[0.25, 0.25, 0.3], [1.0, 1.0, 0.1], [-1.0, -2.0, 0.0], [0.5, -0.5, 0.0]])
    x, lam, _, _ = closest_points_on_triangles(p, *TRI)  # the engine's, which load_map uses
    assert np.allclose(x, [[0.25, 0.25, 0], [0.5, 0.5, 0], [0, 0, 0], [0.5, 0, 0]], atol=1e-15)
    assert np.allclose(lam, [[0.5, 0.25, 0.25], [0, 0.5, 0.5], [1, 0, 0], [0.5, 0.5, 0]])


def test_load_map_keeps_the_force_and_moves_the_moment_by_the_gap():
    """Random forces at points a little off a flat square (two triangles): the mapped forces
    sum to the same total (to round-off), each weight is non-negative, the moment changes by
    exactly Σ (x' - x) × f with x' the foot on the plane, and a force at a vertex stays
    there whole."""
    square = np.array([[[0, 0, 0], [1, 0, 0], [1, 1, 0]], [[0, 0, 0], [1, 1, 0], [0, 1, 0]]], float)
    rng = np.random.default_rng(3)
    pts = np.column_stack([rng.random((40, 2)), rng.normal(0, 1e-3, 40)])
    pts = np.vstack([pts, [[1.0, 1.0, 0.0]]])
    f = rng.normal(size=(41, 3))
    m = load_map(pts, square)
    g = m.forces(f)
    assert np.allclose(g.sum(axis=0), f.sum(axis=0), rtol=0, atol=1e-13)
    assert m.weights.min() >= 0.0 and np.allclose(np.asarray(m.weights.sum(axis=0)), 1.0)
    assert np.allclose(m.moves, np.abs(pts[:, 2]), atol=1e-15)
    centre = np.array([0.3, 0.2, 0.0])
    feet = pts * [1, 1, 0]
    dm = np.cross(feet - pts, f).sum(axis=0)
    lever = np.linalg.norm(pts - centre, axis=1).max()
    want = np.linalg.norm(dm) / (np.linalg.norm(f, axis=1).sum() * lever)
    assert m.moment_error(f, centre) == pytest.approx(want, rel=1e-9)
    corner = np.flatnonzero(np.all(np.isclose(m.points, [1, 1, 0]), axis=1))
    assert len(corner) == 1 and m.weights[corner[0], 40] == pytest.approx(1.0)


def test_bench_refuses_part2_on_another_level():
    """bench compares part 2 with the coupled scapula node by node: one mesh for both."""
    scene = load_scene("shoulder-internal-rotation").with_values(part2_level="medium")
    check_bench(scene, "medium")  # the same level: accepted
    with pytest.raises(SceneError, match="part2_level = 'medium' differs from the bench's"):
        check_bench(scene, "coarse")


@pytest.mark.mpi
def test_part2_on_a_finer_scapula_carries_part1s_loads(comm_tmp):
    """Part 1 at coarse, part 2 on the medium scapula: the loads land on the medium mesh's
    surfaces within a coarse facet's sag, the moment moves by < 1e-3 of Σ|f| × lever, the
    mapped loads balance the springs at part 1's pose as part 1's did, and part 2 runs on the
    medium scapula's DOFs (serial and 2 ranks)."""
    short = ["final_angle=20deg", "output_angle=10deg"]
    scene = load_scene("shoulder-internal-rotation").with_overrides([*short, "part2_level=medium"])
    res = run(scene, "decoupled", level="coarse", out=comm_tmp / "p2medium")
    # a coarse 12.5 mm chord on the glenoid's bone side (R about 28 mm) sags c^2 / 8R = 0.7 mm
    # (measured 0.65 mm); the muscle-scapula contact's master is loaded too (muscle_contact =
    # bones): its nodes reach the glenoid plate's rounded rim, where a coarse chord sags more
    # (measured 1.60 mm, at (-27.7, -5.0, -17.8) mm; 7 of its 555 nodes move over 1 mm)
    assert res.probes["load_map_max_move"] < 2.0e-3
    # the moment moved by the forces times their moves: measured 1.0e-4
    assert max(res.series["load_map_moment_error"]["y"]) < 1e-3
    # part 1 balanced its loads with the springs: the mapped loads still do (total force kept
    # exactly, the moment to the gap) -- a lost load would show here at its own size; measured
    # 6.2e-5 (1.7e-2 when part 2's springs sat at the medium mesh's patch centroids)
    assert res.probes["transfer_equilibrium_residual"] < 1e-3
    # the scapula a decoupled run at medium would load: meshed with the joint (not alone, as
    # part2_level meshes it), its vector P2 DOFs counted (no need to solve that run)
    medium = build(load_scene("shoulder-internal-rotation"), "medium", MPI.COMM_WORLD, "decoupled")
    V = dolfinx.fem.VectorFunctionSpace(medium.meshes["scapula"].mesh, ("Lagrange", 2))
    assert res.dofs_part2 == V.dofmap.index_map.size_global * 3 > 0
