"""The penalty's share of the glenohumeral approach (families/shoulder/compliance.py).

On the coarse rigid-bone mesh, with displacement fields whose answer is known by hand: a rigid
rotation compresses no layer; a uniform strain -e along the unit vector a shortens a layer of
thickness t and normal n by e t (n . a)^2 to first order; the share of a given pressure is the
penalty's overlap over the overlap plus the layers' compressions. Serial and under
``mpirun -n 2`` (the operator works on gathered data: every rank gets the same numbers).
"""

from __future__ import annotations

import dolfinx
import numpy as np
import pytest
from mpi4py import MPI

from shoulder_fem.families.shoulder import model as SH
from shoulder_fem.families.shoulder.compliance import PenaltyShare
from shoulder_fem.scene import load_scene

pytestmark = pytest.mark.mpi


@pytest.fixture(scope="module")
def joint():
    scene = load_scene("shoulder-internal-rotation")
    model = SH.build(scene, "coarse", MPI.COMM_WORLD, "decoupled")
    sm = model.meshes["rigid-bone"]
    ft = SH.head_tags(model, sm.mesh, sm.facet_tags)
    V = dolfinx.fem.VectorFunctionSpace(sm.mesh, ("Lagrange", 2))
    u = dolfinx.fem.Function(V)
    return u, PenaltyShare(u, ft, penalty=6e10)


def _normals(layer) -> tuple[np.ndarray, np.ndarray]:
    d = layer.X_a - layer.X_foot
    t = np.linalg.norm(d, axis=1)
    return d / t[:, None], t


def test_a_rigid_motion_compresses_no_layer(joint):
    u, share = joint
    angle = np.radians(60.0)
    c, s = np.cos(angle), np.sin(angle)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    shift = np.array([[2e-3], [-1e-3], [3e-3]])
    u.interpolate(lambda x: R @ x - x + shift)
    for layer in (share.glenoid, share.humeral):
        x_a, comp = layer.compression()
        # a rigid motion keeps every length: 0 to round-off (mm-sized positions, 1e-12 m)
        assert np.abs(comp).max() < 1e-12
        assert np.allclose(x_a, (R @ layer.X_a.T + shift).T, atol=1e-12)


@pytest.mark.parametrize("which", ["glenoid", "humeral"])
def test_a_uniform_strain_shortens_each_layer_by_strain_times_thickness(joint, which):
    u, share = joint
    layer = getattr(share, which)
    n, t = _normals(layer)
    # the layers' feet are straight below their nodes: the segments are about as long as the
    # layers are thick (1.5 and 2 mm nominal; measured at coarse 0.88-2.94 mm, the glenoid's
    # thicker towards its rim)
    assert 0.5e-3 < t.min() and t.max() < 3.5e-3
    a = n.mean(axis=0) / np.linalg.norm(n.mean(axis=0))
    e = 1e-4
    u.interpolate(lambda x: -e * np.outer(a, a @ x))
    _, comp = layer.compression()
    # |d| - |(I - e a a^T) d| = e t (n . a)^2 + O(e^2 t): exact on the linear field but for the
    # relative O(e) = 1e-4 second-order term (the foot's linear interpolation is exact)
    expected = e * t * (n @ a) ** 2
    assert np.allclose(comp, expected, rtol=1e-3, atol=1e-12)
    assert MPI.COMM_WORLD.allgather(float(comp.sum())) == [float(comp.sum())] * MPI.COMM_WORLD.size


def test_the_share_is_the_overlap_over_the_approach(joint):
    u, share = joint
    u.x.array[:] = 0.0
    pts = share.glenoid.X_a[:3]
    p = np.array([1e5, 3e5, 0.0])
    # no layer compressed: the approach is the penalty's overlap alone
    out = share(pts, p)
    assert out["share"] == pytest.approx(1.0, abs=1e-12)
    # by hand: sum p (p / eps) / sum p, eps = 6e10 Pa/m; the zero-pressure node does not count
    assert out["overlap"] == pytest.approx((1e5**2 + 3e5**2) / 4e5 / 6e10, rel=1e-12)
    # the glenoid layer compressed by e t (n . a)^2: its pressure-weighted mean is the layers' sum
    n, t = _normals(share.glenoid)
    a = n[:2].mean(axis=0) / np.linalg.norm(n[:2].mean(axis=0))
    e = 1e-3
    u.interpolate(lambda x: -e * np.outer(a, a @ x))
    out = share(pts, p)
    c = e * t[:2] * (n[:2] @ a) ** 2
    glenoid = (1e5 * c[0] + 3e5 * c[1]) / 4e5
    # first order in e = 1e-3: the second-order term is relatively O(e)
    assert out["glenoid_layer"] == pytest.approx(glenoid, rel=2e-3)
    approach = out["overlap"] + out["glenoid_layer"] + out["humeral_layer"]
    assert out["share"] == pytest.approx(out["overlap"] / approach, rel=1e-12)
    assert share(pts, np.zeros(3))["share"] == 0.0
