"""Kinematics of a displacement field, as UFL expressions.

All quantities are dimensionless (strains, stretches, invariants) and are written in the
reference (body-frame) coordinates: ``grad`` is the gradient with respect to the reference
position X. The invariants below are those of a symmetric second-order tensor such as the right
Cauchy-Green tensor C = F^T F.
"""

from __future__ import annotations

import ufl

__all__ = [
    "deformation_gradient",
    "green_lagrange",
    "invariants",
    "isochoric_invariants",
    "linear_strain",
    "right_cauchy_green",
]


def _identity_like(tensor: ufl.core.expr.Expr) -> ufl.core.expr.Expr:
    """Identity tensor of the dimension of a square tensor (or of a vector's length)."""
    return ufl.Identity(ufl.shape(tensor)[0])


def deformation_gradient(u: ufl.core.expr.Expr) -> ufl.core.expr.Expr:
    """Deformation gradient F = I + grad u (dimensionless).

    Args:
        u: Displacement field in m (a vector UFL expression, e.g. a dolfinx Function).

    Returns:
        The tensor F, dimensionless.
    """
    return _identity_like(u) + ufl.grad(u)


def right_cauchy_green(F: ufl.core.expr.Expr) -> ufl.core.expr.Expr:
    """Right Cauchy-Green tensor C = F^T F (dimensionless).

    Args:
        F: Deformation gradient, dimensionless.

    Returns:
        The symmetric tensor C, dimensionless.
    """
    return F.T * F


def green_lagrange(F: ufl.core.expr.Expr) -> ufl.core.expr.Expr:
    """Green-Lagrange strain E = (C - I)/2 (dimensionless).

    Args:
        F: Deformation gradient, dimensionless.

    Returns:
        The symmetric tensor E, dimensionless.
    """
    return (right_cauchy_green(F) - _identity_like(F)) / 2


def linear_strain(u: ufl.core.expr.Expr) -> ufl.core.expr.Expr:
    """Infinitesimal strain eps = sym(grad u) (dimensionless).

    Args:
        u: Displacement field in m.

    Returns:
        The symmetric tensor eps, dimensionless.
    """
    return ufl.sym(ufl.grad(u))


def invariants(
    C: ufl.core.expr.Expr,
) -> tuple[ufl.core.expr.Expr, ufl.core.expr.Expr, ufl.core.expr.Expr]:
    """Principal invariants of a second-order tensor.

    I1 = tr C, I2 = ((tr C)^2 - tr(C C))/2, I3 = det C.

    Args:
        C: Square tensor, typically the right Cauchy-Green tensor (dimensionless).

    Returns:
        (I1, I2, I3), dimensionless.
    """
    i1 = ufl.tr(C)
    i2 = (i1**2 - ufl.tr(ufl.dot(C, C))) / 2
    i3 = ufl.det(C)
    return i1, i2, i3


def isochoric_invariants(
    C: ufl.core.expr.Expr,
) -> tuple[ufl.core.expr.Expr, ufl.core.expr.Expr, ufl.core.expr.Expr]:
    """Invariants of the isochoric part of C, and the volume ratio.

    J = sqrt(det C), I1bar = J^(-2/3) I1, I2bar = J^(-4/3) I2 (three-dimensional definition:
    the isochoric tensor is Cbar = J^(-2/3) C).

    Args:
        C: Right Cauchy-Green tensor, 3x3, dimensionless.

    Returns:
        (I1bar, I2bar, J), dimensionless.

    Raises:
        ValueError: If C is not a 3x3 tensor.
    """
    if ufl.shape(C) != (3, 3):
        raise ValueError(f"isochoric_invariants needs a 3x3 tensor, got shape {ufl.shape(C)}")
    i1, i2, i3 = invariants(C)
    J = ufl.sqrt(i3)
    return J ** (-2 / 3) * i1, J ** (-4 / 3) * i2, J
