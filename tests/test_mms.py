"""Linear elasticity by the method of manufactured solutions: convergence rates of P1 and P2.

The exact displacement is written once (``u_exact``) for both UFL and numpy. The body force is
f = -div sigma(eps(u_exact)), the Dirichlet data u_exact on the whole boundary; the problem is
assembled from ``internal_power_linear`` and ``body_force_power`` and solved with MUMPS. The
errors must fall as h^(p+1) in L2 and h^p in the H1 seminorm.
"""

from __future__ import annotations

import types

import dolfinx
import dolfinx.fem.petsc
import numpy as np
import pytest
import ufl
from mpi4py import MPI

from shoulder_fem.forms import (
    LinearElastic,
    body_force_power,
    internal_power_linear,
    linear_strain,
)

MATERIAL = LinearElastic(youngs_modulus=1.0, poisson_ratio=0.3)  # Pa; scale-free problem
MESH_SIZES = {1: [4, 8, 16], 2: [2, 4, 8]}  # cells per side, per element degree
RATE_TOLERANCE = 0.2


def u_exact(x, m: types.ModuleType) -> list:
    """Manufactured displacement, m, with a non-zero divergence (so lmbda matters).

    Args:
        x: Coordinates: ``ufl.SpatialCoordinate`` or a numpy array of shape (3, N).
        m: The module providing sin, cos and pi: ``ufl`` or ``numpy``.
    """
    return [
        m.sin(m.pi * x[0] * x[1]),
        m.cos(m.pi * x[1] * x[2]),
        m.sin(m.pi * x[0] * x[2]) * x[1],
    ]


def solve_and_measure(n: int, degree: int) -> tuple[float, float]:
    """Solve on an n^3 unit cube with P``degree``; return (L2 error, H1-seminorm error), m."""
    comm = MPI.COMM_WORLD
    mesh = dolfinx.mesh.create_unit_cube(comm, n, n, n)
    V = dolfinx.fem.VectorFunctionSpace(mesh, ("CG", degree))
    dx = ufl.Measure("dx", domain=mesh)

    x = ufl.SpatialCoordinate(mesh)
    ue = ufl.as_vector(u_exact(x, ufl))
    f = -ufl.div(MATERIAL.stress(linear_strain(ue)))
    u, w = ufl.TrialFunction(V), ufl.TestFunction(V)
    a = internal_power_linear(MATERIAL, u, w, dx)
    L = body_force_power(1.0, f, w, dx)

    tdim = mesh.topology.dim
    mesh.topology.create_connectivity(tdim - 1, tdim)
    facets = dolfinx.mesh.exterior_facet_indices(mesh.topology)
    u_bc = dolfinx.fem.Function(V)
    u_bc.interpolate(lambda x: np.stack(u_exact(x, np)))
    bc = dolfinx.fem.dirichletbc(u_bc, dolfinx.fem.locate_dofs_topological(V, tdim - 1, facets))

    problem = dolfinx.fem.petsc.LinearProblem(
        a,
        L,
        bcs=[bc],
        petsc_options={
            "ksp_type": "preonly",
            "pc_type": "lu",
            "pc_factor_mat_solver_type": "mumps",
        },
    )
    uh = problem.solve()
    assert problem.solver.getConvergedReason() > 0

    dxe = ufl.Measure("dx", domain=mesh, metadata={"quadrature_degree": 2 * degree + 3})
    e = uh - ue
    errors = []
    for integrand in (ufl.inner(e, e), ufl.inner(ufl.grad(e), ufl.grad(e))):
        local = dolfinx.fem.assemble_scalar(dolfinx.fem.form(integrand * dxe))
        errors.append(np.sqrt(comm.allreduce(local, op=MPI.SUM)))
    return errors[0], errors[1]


def rates(errors: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Observed orders of convergence between successive meshes."""
    return np.log(errors[:-1] / errors[1:]) / np.log(h[:-1] / h[1:])


@pytest.mark.mpi
@pytest.mark.parametrize("degree", [1, 2])
def test_linear_elasticity_convergence_rates(degree):
    """L2 error falls as h^(p+1), H1-seminorm error as h^p."""
    sizes = MESH_SIZES[degree]
    h = 1.0 / np.array(sizes, dtype=float)
    e_l2, e_h1 = np.array([solve_and_measure(n, degree) for n in sizes]).T
    r_l2, r_h1 = rates(e_l2, h), rates(e_h1, h)
    print(f"P{degree}: h={h}, L2 {e_l2} rates {r_l2}, H1 {e_h1} rates {r_h1}")
    np.testing.assert_allclose(r_l2, degree + 1, atol=RATE_TOLERANCE)
    np.testing.assert_allclose(r_h1, degree, atol=RATE_TOLERANCE)
