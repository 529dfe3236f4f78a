"""The decoupled method's part 2 on a driven body: eq. (13) in the floating frame, and its variants.

Owns the residual for the straining displacement ũ (body-frame components), linear elastic:
``paper`` takes the rigid-frame inertia at the rigid position GM as published;
``spin-softening`` takes it at the strained position GM + ũ; ``stress-stiffening`` adds to that
the geometric stiffness of the centrifugal prestress ω²σ1, σ1 the stress of one static solve at
ω = 1 rad/s (:func:`unit_centrifugal_prestress`).
"""

from __future__ import annotations

import dolfinx
import numpy as np
import ufl

from shoulder_fem.engine.fem import constant
from shoulder_fem.engine.newmark import NewmarkState
from shoulder_fem.engine.solver import NonlinearSolver
from shoulder_fem.families.base import SolverOptions
from shoulder_fem.families.driven_body.frame import FloatingFrame
from shoulder_fem.families.driven_body.model import DrivenBody, quadrature
from shoulder_fem.forms import kinematics, materials
from shoulder_fem.forms import virtual_power as vp

#: The variants whose rigid-frame inertia acts at the strained position GM + ũ.
STRAINED_VARIANTS = ("spin-softening", "stress-stiffening")


def floating_frame_residual(
    model: DrivenBody,
    frame: FloatingFrame,
    state: NewmarkState,
    dt: ufl.core.expr.Expr,
    material: materials.LinearElastic,
    w: ufl.Argument,
    dx: ufl.Measure,
) -> ufl.Form:
    """Eq. (13) for ``state.u`` without the stress-stiffening term (N·m/s per unit test speed).

    ∫σ(ε(ũ)):ε(w) + ∫ρ(ũ̈ + 2Ω×ũ̇)·w + ∫ρ(a_G + Ω̇×GM + Ω×(Ω×GM))·w, GM replaced by GM + ũ in
    the strained variants; with ``quasi_static`` the ũ̈ and Coriolis terms are dropped. ``dt``
    is the step's Δt (a Constant, s), ``w`` the test function.
    """
    rho = model.density
    u = state.u
    position = frame.gm + u if model.variant in STRAINED_VARIANTS else frame.gm
    residual = (
        vp.internal_power_linear(material, u, w, dx)
        + vp.translational_inertia(rho, frame.a_g, w, dx)
        + vp.euler_inertia(rho, frame.domega, position, w, dx)
        + vp.centrifugal_inertia(rho, frame.omega, position, w, dx)
    )
    if not model.quasi_static:
        residual += vp.relative_inertia(rho, state.acceleration(dt), w, dx)
        residual += vp.coriolis_inertia(rho, frame.omega, state.velocity(dt), w, dx)
    return residual


def unit_centrifugal_prestress(
    model: DrivenBody,
    V: dolfinx.fem.FunctionSpace,
    material: materials.LinearElastic,
    rho: float,
    gm: ufl.core.expr.Expr,
    x_g: np.ndarray,
    bc: dolfinx.fem.DirichletBCMetaClass,
    dx: ufl.Measure,
    options: SolverOptions | None,
) -> ufl.core.expr.Expr:
    """Stress (Pa) of the steady linear response to the centrifugal load at ω = 1 rad/s.

    The stress-stiffening variant scales it by ω(t)² and adds its geometric stiffness: the
    prestress of a spinning body in the quasi-steady approximation.
    """
    unit = dolfinx.fem.Function(V, name="unit_spin_displacement")
    w = ufl.TestFunction(V)
    e = constant(model.mesh, model.axis)
    # The centrifugal acceleration about the spin axis through O: that of G plus that about G.
    a_g = constant(model.mesh, np.cross(model.axis, np.cross(model.axis, x_g)))
    residual = (
        vp.internal_power_linear(material, unit, w, dx)
        + vp.translational_inertia(rho, a_g, w, dx)
        + vp.centrifugal_inertia(rho, e, gm, w, dx)
    )
    solver = NonlinearSolver(
        residual,
        unit,
        [bc],
        name="prestress",
        linear=True,
        options=options,
        form_compiler_params=quadrature(model),
    )
    solver.solve(step="unit centrifugal prestress")
    solver.destroy()
    return material.stress(kinematics.linear_strain(unit))
