"""The soft tissues' trial-state check (``families/shoulder/trial.py``) on one P2 tetrahedron.

The displacement u = c X0² e0 is quadratic, so the P2 space holds it exactly, and by hand
F = I + 2 c X0 e0⊗e0, J = 1 + 2 c X0 and C = F^T F, I1bar = J^(-2/3) ((1 + 2 c X0)² + 2). With
c = -0.6 the element folds at its vertex X0 = 1 (J = -0.2) while J > 0 wherever X0 < 1/1.2.
"""

from __future__ import annotations

import basix
import dolfinx
import numpy as np
import pytest
import ufl
from mpi4py import MPI

from shoulder_fem.families.shoulder.trial import SoftTissueCheck
from shoulder_fem.meshes import shoulder as S

#: serial and under mpirun -n 2 (rank 0 owns the cell, rank 1 none: the check is collective)
pytestmark = pytest.mark.mpi

C = -0.6


def _one_tet(comm):
    """One soft-tissue P2 tetrahedron (rank 0 owns it) and its displacement u = c X0² e0."""
    points = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
    cells = np.array([[0, 1, 2, 3]], dtype=np.int64)
    if comm.rank != 0:
        points, cells = np.zeros((0, 3)), np.zeros((0, 4), dtype=np.int64)
    domain = ufl.Mesh(ufl.VectorElement("Lagrange", ufl.tetrahedron, 1))
    mesh = dolfinx.mesh.create_mesh(comm, cells, points, domain)
    n = mesh.topology.index_map(3).size_local
    tags = dolfinx.mesh.meshtags(
        mesh, 3, np.arange(n, dtype=np.int32), np.full(n, S.SUBSCAPULARIS.id, dtype=np.int32)
    )
    u = dolfinx.fem.Function(dolfinx.fem.VectorFunctionSpace(mesh, ("Lagrange", 2)))
    u.interpolate(lambda x: np.vstack([C * x[0] ** 2, 0 * x[0], 0 * x[0]]))
    return mesh, tags, u


def _gathered(comm, arrays):
    return [np.concatenate(comm.allgather(a)) for a in arrays]


def test_a_folded_corner_fails_at_the_nodes_and_passes_at_the_quadrature_points():
    """The nodes see the fold (J = 1 + 2c at the vertex X0 = 1), the degree-4 quadrature points
    do not (all of them have X0 < 0.8); the values at both are the hand formulas."""
    comm = MPI.COMM_WORLD
    _, tags, u = _one_tet(comm)
    nodes = SoftTissueCheck(u, tags)
    quad = SoftTissueCheck(u, tags, "quadrature", 4)
    points, _ = basix.make_quadrature(basix.CellType.tetrahedron, 4)
    assert points[:, 0].max() < 0.8  # the hand condition X0 < 1/1.2 with room
    J, i1bar = _gathered(comm, quad.values(guard=True))
    j_hand = 1 + 2 * C * points[:, 0]
    assert J == pytest.approx(j_hand, abs=1e-12)
    assert i1bar == pytest.approx(j_hand ** (-2 / 3) * (j_hand**2 + 2), rel=1e-12)
    J_nodes, _ = _gathered(comm, nodes.values())
    assert J_nodes.min() == pytest.approx(1 + 2 * C, abs=1e-12)  # the vertex (1, 0, 0)
    assert nodes.j_range()[0] == pytest.approx(1 + 2 * C, abs=1e-12)
    assert quad.j_range()[0] == pytest.approx(1 + 2 * C, abs=1e-12)  # recorded at the nodes
    assert not nodes.admissible()
    assert quad.admissible()


def test_an_unknown_trial_check_is_refused_by_name():
    _, tags, u = _one_tet(MPI.COMM_WORLD)
    with pytest.raises(ValueError, match="trial_check = 'centroid'"):
        SoftTissueCheck(u, tags, "centroid")
