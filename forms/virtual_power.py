"""Terms of the virtual power, one function per term (paper, eqs. (1), (2) and (13)).

Every function returns a UFL form that is linear in the virtual velocity (test field) ``w``. With
``w`` a ``ufl.TestFunction`` the result is a 1-form (a residual vector once assembled); with ``w``
a known field (a Function, a Constant, an expression) it is a functional, in W (J/s) when ``w`` is
a velocity in m/s.

Sign convention. The residual of the momentum balance is

    R(u; w) = P_int + P_acc - P_ext = 0   for every admissible w,

with P_int the internal power (``internal_power_finite`` or ``internal_power_linear``), P_acc
every inertia term, i.e. every term of the form int rho a.w (``translational_inertia``,
``euler_inertia``, ``centrifugal_inertia``, ``coriolis_inertia``, ``relative_inertia`` in the
floating frame; ``inertia_power`` in the inertial frame), and P_ext the power of the applied
loads (``body_force_power``, ``traction_power``). Each function returns its integral with a plus
sign, exactly as in its docstring; the caller combines them with the signs above. In the floating
frame this is the paper's eq. (13) moved to one side:

    int sigma : grad w + int rho (a_G + dOmega x GM + Omega x (Omega x GM) + dv + 2 Omega x v).w
        - int rho b.w - int t.w = 0.

Frame quantities. a_G (m/s^2), Omega (rad/s), dOmega (rad/s^2) and the centre of mass X_G (m)
are best passed as dolfinx ``Constant``s (any UFL vector works), so a form is compiled once and
reused for every frame of a motion by updating the constants. ``gm`` is the position of a point
relative to the centre of mass, GM = x - X_G with x = ``ufl.SpatialCoordinate(mesh)``, in
body-frame (floating-frame) components, m. Vectors are three-dimensional (``ufl.cross``).

Units: rho in kg/m^3, b in m/s^2 (force per unit mass), t in Pa (force per unit area),
accelerations in m/s^2, velocities in m/s.
"""

from __future__ import annotations

import ufl

from .kinematics import deformation_gradient, linear_strain
from .materials import Hyperelastic, LinearElastic, Scalar

__all__ = [
    "body_force_power",
    "centrifugal_inertia",
    "coriolis_inertia",
    "euler_inertia",
    "geometric_stiffness",
    "inertia_power",
    "internal_power_finite",
    "internal_power_linear",
    "relative_inertia",
    "rigid_frame_inertia",
    "traction_power",
    "translational_inertia",
]

Vector = ufl.core.expr.Expr
"""A UFL vector expression (Function, Constant, TestFunction, as_vector(...), ...)."""


def internal_power_finite(
    material: Hyperelastic, u: Vector, w: Vector, dx: ufl.Measure
) -> ufl.Form:
    """Internal power at finite strain, int P(F(u)) : grad w dx.

    Args:
        material: Any hyperelastic law (provides ``first_piola``).
        u: Displacement, m.
        w: Virtual velocity (test field).
        dx: Cell measure.

    Returns:
        The form; P in Pa.
    """
    P = material.first_piola(deformation_gradient(u))
    return ufl.inner(P, ufl.grad(w)) * dx


def internal_power_linear(
    material: LinearElastic, u: Vector, w: Vector, dx: ufl.Measure
) -> ufl.Form:
    """Internal power at small strain, int sigma(eps(u)) : eps(w) dx.

    Args:
        material: Linear elastic law (provides ``stress``).
        u: Displacement, m (a Function, or a TrialFunction for a bilinear form).
        w: Virtual velocity (test field).
        dx: Cell measure.

    Returns:
        The form; sigma in Pa.
    """
    return ufl.inner(material.stress(linear_strain(u)), linear_strain(w)) * dx


def body_force_power(rho: Scalar, b: Vector, w: Vector, dx: ufl.Measure) -> ufl.Form:
    """External power of body forces, int rho b.w dx.

    Args:
        rho: Density, kg/m^3.
        b: Body force per unit mass (e.g. gravity), m/s^2.
        w: Virtual velocity (test field).
        dx: Cell measure.
    """
    return rho * ufl.dot(b, w) * dx


def traction_power(t: Vector, w: Vector, ds: ufl.Measure) -> ufl.Form:
    """External power of surface tractions, int t.w ds.

    Args:
        t: Traction, Pa (force per unit reference area).
        w: Virtual velocity (test field).
        ds: Facet measure (restrict it to the loaded boundary, e.g. ``ds(tag)``).
    """
    return ufl.dot(t, w) * ds


def translational_inertia(rho: Scalar, a_G: Vector, w: Vector, dx: ufl.Measure) -> ufl.Form:
    """Rigid-frame translational inertia, int rho a_G.w dx.

    Args:
        rho: Density, kg/m^3.
        a_G: Acceleration of the centre of mass, m/s^2, in body-frame components.
        w: Virtual velocity (test field).
        dx: Cell measure.
    """
    return rho * ufl.dot(a_G, w) * dx


def euler_inertia(rho: Scalar, dOmega: Vector, gm: Vector, w: Vector, dx: ufl.Measure) -> ufl.Form:
    """Rigid-frame Euler (angular acceleration) inertia, int rho (dOmega x GM).w dx.

    Args:
        rho: Density, kg/m^3.
        dOmega: Angular acceleration of the frame, rad/s^2, body-frame components.
        gm: Position relative to the centre of mass, GM, m.
        w: Virtual velocity (test field).
        dx: Cell measure.
    """
    return rho * ufl.dot(ufl.cross(dOmega, gm), w) * dx


def centrifugal_inertia(
    rho: Scalar, Omega: Vector, gm: Vector, w: Vector, dx: ufl.Measure
) -> ufl.Form:
    """Rigid-frame centrifugal inertia, int rho (Omega x (Omega x GM)).w dx.

    Args:
        rho: Density, kg/m^3.
        Omega: Angular velocity of the frame, rad/s, body-frame components.
        gm: Position relative to the centre of mass, GM, m.
        w: Virtual velocity (test field).
        dx: Cell measure.
    """
    return rho * ufl.dot(ufl.cross(Omega, ufl.cross(Omega, gm)), w) * dx


def coriolis_inertia(
    rho: Scalar, Omega: Vector, v_rel: Vector, w: Vector, dx: ufl.Measure
) -> ufl.Form:
    """Coriolis inertia, int rho 2 (Omega x v).w dx, v the straining velocity.

    Args:
        rho: Density, kg/m^3.
        Omega: Angular velocity of the frame, rad/s, body-frame components.
        v_rel: Straining (relative) velocity v-tilde, m/s, body-frame components.
        w: Virtual velocity (test field).
        dx: Cell measure.
    """
    return 2 * rho * ufl.dot(ufl.cross(Omega, v_rel), w) * dx


def relative_inertia(rho: Scalar, a_rel: Vector, w: Vector, dx: ufl.Measure) -> ufl.Form:
    """Straining (relative) acceleration inertia, int rho dv.w dx.

    Args:
        rho: Density, kg/m^3.
        a_rel: Straining acceleration relative to the rigid configuration (paper's v-tilde dot,
            e.g. its Jaumann estimate), m/s^2, body-frame components.
        w: Virtual velocity (test field).
        dx: Cell measure.
    """
    return rho * ufl.dot(a_rel, w) * dx


def rigid_frame_inertia(
    rho: Scalar,
    a_G: Vector,
    Omega: Vector,
    dOmega: Vector,
    gm: Vector,
    w: Vector,
    dx: ufl.Measure,
) -> ufl.Form:
    """Sum of the three rigid-frame inertia terms: translational + Euler + centrifugal.

    int rho (a_G + dOmega x GM + Omega x (Omega x GM)).w dx; arguments as in the single terms.
    """
    return (
        translational_inertia(rho, a_G, w, dx)
        + euler_inertia(rho, dOmega, gm, w, dx)
        + centrifugal_inertia(rho, Omega, gm, w, dx)
    )


def inertia_power(rho: Scalar, a: Vector, w: Vector, dx: ufl.Measure) -> ufl.Form:
    """Inertia in an inertial frame, int rho a.w dx (coupled method).

    Args:
        rho: Density in the reference configuration, kg/m^3.
        a: Absolute acceleration, m/s^2.
        w: Virtual velocity (test field).
        dx: Cell measure.
    """
    return rho * ufl.dot(a, w) * dx


def geometric_stiffness(prestress, u: Vector, w: Vector, dx: ufl.Measure) -> ufl.Form:
    """Geometric stiffness of a prestress σ0 (stress stiffening), int σ0 : (grad u)ᵀ grad w dx.

    The second-order work of an initial stress on a small displacement: in index form
    σ0_ij ∂_i u_k ∂_j w_k. Added to the linear internal power it stiffens a body in tension
    (a spinning beam's bending frequency rises with its centrifugal prestress).

    Args:
        prestress: σ0, Pa (a UFL tensor, e.g. the stress of a previous linear solution).
        u: Displacement, m.
        w: Virtual velocity (test field).
        dx: Cell measure.
    """
    return ufl.inner(ufl.grad(u) * prestress, ufl.grad(w)) * dx
