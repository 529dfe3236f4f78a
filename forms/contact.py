"""Contact against analytic rigid surfaces as UFL forms (penalty), for small models and checks.

The general contact code (:mod:`shoulder_fem.engine.contact`) pairs slave quadrature points
with master facets found by a spatial search, which UFL cannot express. Against an analytic
rigid surface the gap is a closed-form function of the current position x = X + u, and the
penalty contact power is an ordinary boundary integral:

    P_c(u; w) = - int_Gs  eps <-g(x)>  n(x) . w  dA,        <a> = max(a, 0),

with g the signed distance to the surface (negative when penetrating) and n its outward unit
normal (pointing out of the rigid solid, towards the slave). ``ufl.derivative`` gives the exact
tangent, curvature term included. The tests use these forms to check the numpy assembly of
:mod:`shoulder_fem.engine.contact` entry by entry.
"""

from __future__ import annotations

import ufl

Vector = ufl.core.expr.Expr


def plane_gap(u: Vector, point, normal) -> tuple[ufl.core.expr.Expr, ufl.core.expr.Expr]:
    """Signed gap (m) and outward normal of a rigid plane through ``point`` with unit ``normal``.

    Args:
        u: Displacement (m).
        point: A point of the plane (UFL vector, m).
        normal: Unit normal pointing out of the rigid solid (UFL vector).
    """
    X = ufl.SpatialCoordinate(u.ufl_function_space().mesh)
    return ufl.dot(X + u - point, normal), normal


def sphere_gap(
    u: Vector, centre, radius, concave: bool = False
) -> tuple[ufl.core.expr.Expr, ufl.core.expr.Expr]:
    """Signed gap (m) and outward normal of a rigid sphere.

    Args:
        u: Displacement (m).
        centre: Centre of the sphere (UFL vector, m).
        radius: Radius (m).
        concave: False: a rigid ball, the slave outside it. True: a rigid socket, the slave
            inside the spherical cavity.
    """
    X = ufl.SpatialCoordinate(u.ufl_function_space().mesh)
    d = X + u - centre
    r = ufl.sqrt(ufl.dot(d, d))
    if concave:
        return radius - r, -d / r
    return r - radius, d / r


def penalty_contact_power(
    gap: ufl.core.expr.Expr, normal, penalty, w: Vector, ds: ufl.Measure
) -> ufl.Form:
    """Penalty contact term of the residual, - int eps <-g> n . w ds (N).

    Args:
        gap: Signed gap g (m), negative when penetrating.
        normal: Outward normal of the master surface.
        penalty: Penalty stiffness eps (Pa/m).
        w: Test field.
        ds: Facet measure restricted to the slave surface.
    """
    pressure = penalty * ufl.conditional(ufl.lt(gap, 0.0), -gap, 0.0)
    return -pressure * ufl.dot(normal, w) * ds
