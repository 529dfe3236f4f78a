"""Rigid-body functionals (paper, eqs. (6), (7), (10)) as scalar UFL forms.

Each function returns scalar forms (a single form, or a list / nested list of them). The caller
compiles them with ``dolfinx.fem.form``, assembles each with ``assemble_scalar`` and sums over
ranks with ``comm.allreduce(value, op=MPI.SUM)``.

Units: rho in kg/m^3, positions in m, tractions in Pa. Mass in kg, first moment in kg m,
inertia tensor in kg m^2, force in N, moment in N m.
"""

from __future__ import annotations

import ufl

from .materials import Scalar

__all__ = [
    "first_moment",
    "inertia_tensor",
    "mass",
    "resultant_force",
    "resultant_moment",
]


def _dim(vector: ufl.core.expr.Expr) -> int:
    """Length of a UFL vector."""
    return ufl.shape(vector)[0]


def mass(rho: Scalar, dx: ufl.Measure) -> ufl.Form:
    """Mass m = int rho dx, kg.

    Args:
        rho: Density, kg/m^3 (number, Constant or Function).
        dx: Cell measure carrying the mesh (``ufl.Measure("dx", domain=mesh)``).
    """
    return ufl.as_ufl(rho) * dx


def first_moment(rho: Scalar, x: ufl.core.expr.Expr, dx: ufl.Measure) -> list[ufl.Form]:
    """First moment of mass, [int rho x_i dx], kg m; divide by the mass for the centre X_G.

    Args:
        rho: Density, kg/m^3.
        x: Position, m, usually ``ufl.SpatialCoordinate(mesh)``.
        dx: Cell measure.
    """
    return [rho * x[i] * dx for i in range(_dim(x))]


def inertia_tensor(rho: Scalar, gm: ufl.core.expr.Expr, dx: ufl.Measure) -> list[list[ufl.Form]]:
    """Inertia tensor about G, I_G = int rho (|GM|^2 delta - GM x GM) dx, kg m^2.

    Args:
        rho: Density, kg/m^3.
        gm: Position relative to the centre of mass, GM = x - X_G, m.
        dx: Cell measure.

    Returns:
        Nested list ``forms[i][j]`` of the components (I_G)_ij.
    """
    n = _dim(gm)
    r2 = ufl.dot(gm, gm)
    return [
        [rho * ((r2 if i == j else 0) - gm[i] * gm[j]) * dx for j in range(n)] for i in range(n)
    ]


def resultant_force(t: ufl.core.expr.Expr, ds: ufl.Measure) -> list[ufl.Form]:
    """Resultant of surface tractions, [int t_i ds], N.

    Args:
        t: Traction, Pa.
        ds: Facet measure (restricted to the loaded boundary if needed).
    """
    return [t[i] * ds for i in range(_dim(t))]


def resultant_moment(
    t: ufl.core.expr.Expr, gm: ufl.core.expr.Expr, ds: ufl.Measure
) -> list[ufl.Form]:
    """Moment of surface tractions about G, [int (GM x t)_i ds], N m.

    Args:
        t: Traction, Pa.
        gm: Position relative to the centre of mass, GM, m (three-dimensional).
        ds: Facet measure.
    """
    moment = ufl.cross(gm, t)
    return [moment[i] * ds for i in range(3)]
