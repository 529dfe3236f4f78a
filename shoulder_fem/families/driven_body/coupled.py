"""Method #1 on the driven body, coupled: finite-strain dynamics in the inertial frame.

Owns :class:`InertialFrameProblem`: the total displacement of a Saint Venant–Kirchhoff body, its
clamped face following the hub, one Newton solve per Newmark step; and :func:`run_coupled`,
which marches it with the time loop both methods share.
"""

from __future__ import annotations

import dolfinx
import numpy as np
import ufl

from shoulder_fem.engine.fem import constant
from shoulder_fem.engine.newmark import NewmarkState
from shoulder_fem.engine.solver import NonlinearSolver
from shoulder_fem.families.base import RunContext, SolverOptions
from shoulder_fem.families.driven_body.model import (
    DrivenBody,
    clamp_dofs,
    dof_coordinates,
    quadrature,
    vector_space,
)
from shoulder_fem.families.driven_body.outputs import BodyOutputs, LastStep, boundary_reaction
from shoulder_fem.families.driven_body.stepping import MethodSteps, march_driven_body
from shoulder_fem.forms import kinematics, materials
from shoulder_fem.forms import virtual_power as vp


class InertialFrameProblem:
    """The driven body's total displacement u (inertial frame, x = X + u), clamped to the hub.

    The momentum balance ∫ρ ü·w + ∫P(F):∇w = 0 of a Saint Venant–Kirchhoff body, integrated
    with the Newmark rule; the clamped face follows the hub exactly (u = R(θ)X − X). Each step
    starts from the previous deformed configuration rotated by the hub's increment, so Newton
    sees only the straining correction.

    Args:
        model: the driven body.
        options: PETSc options overriding the solver's defaults.
    """

    def __init__(self, model: DrivenBody, options: SolverOptions | None = None):
        self.model = model
        mesh = model.mesh
        V = vector_space(model)
        self.X = ufl.SpatialCoordinate(mesh)
        w = ufl.TestFunction(V)
        dx = ufl.Measure("dx", domain=mesh, metadata=quadrature(model))
        self.state = NewmarkState(V, "displacement", model.numerical_damping)
        u = self.u = self.state.u
        self.dt = constant(mesh, model.times[1] - model.times[0])
        self.rot = constant(mesh, np.eye(3))  # hub rotation R(θ) at the end of the step
        self.material = materials.SaintVenantKirchhoff(model.youngs_modulus, model.poisson_ratio)
        residual = vp.inertia_power(model.density, self.state.acceleration(self.dt), w, dx)
        residual += vp.internal_power_finite(self.material, u, w, dx)

        self.dofs = clamp_dofs(model, V)
        self.u_clamp = dolfinx.fem.Function(V)
        bc = dolfinx.fem.dirichletbc(self.u_clamp, self.dofs)
        force_scale = model.youngs_modulus * model.area
        self.solver = NonlinearSolver(
            residual,
            u,
            [bc],
            name="coupled",
            # Round-off floor of the residual: element forces of order E·A·|∇u| cancel to ~1e-16
            # of that; a slender beam turning by metres reaches ~1e-13 E A. Converge at
            # 1e-12 E A, or when the Newton step is at round-off relative to the displacement.
            options={"snes_atol": 1e-12 * force_scale, "snes_stol": 1e-12, **(options or {})},
            form_compiler_params=quadrature(model),
        )
        self.residual_form = dolfinx.fem.form(residual, form_compiler_params=quadrature(model))
        self.Xd = dof_coordinates(V)
        self.body_u = dolfinx.fem.Function(V, name="strain_displacement")
        self.last = LastStep()

    def outputs(self) -> BodyOutputs:
        """Body-frame measures: ũ = Rᵀ(X + u) − X; the Cauchy stress rotated into the body frame."""
        u, rot = self.u, self.rot
        F = kinematics.deformation_gradient(u)
        S = self.material.second_piola(kinematics.right_cauchy_green(F))
        sigma = F * S * F.T / ufl.det(F)
        return BodyOutputs(self.model, rot.T * (self.X + u) - self.X, rot.T * sigma * rot)

    def advance(self, t0: float, t1: float) -> None:
        """Solve the step from ``t0`` to ``t1`` (s); store the clamp reaction in :attr:`last`."""
        model, u, Xd = self.model, self.u, self.Xd
        self.dt.value = t1 - t0
        r0, r1 = model.motion.rotation(t0), model.motion.rotation(t1)
        self.rot.value[:] = r1
        self.u_clamp.x.array[:] = (Xd @ r1.T - Xd).ravel()
        x_prev = Xd + self.state.u_n.x.array.reshape(-1, 3)
        u.x.array[:] = (x_prev @ (r1 @ r0.T).T - Xd).ravel()  # rotate the last configuration
        self.solver.solve(step=f"t = {t1:.6g} s")
        # Clamp reaction now, while the Newmark acceleration in the form is this step's.
        self.last.reaction, self.last.moment = boundary_reaction(
            self.residual_form, self.dofs, model.mesh.comm, Xd, rotation=r1
        )
        self.state.advance(t1 - t0)

    def frame(self, t: float) -> None:
        """Set the hub rotation of the body-frame measures to that at ``t`` (s)."""
        self.rot.value[:] = self.model.motion.rotation(t)

    def snapshot(self, t: float) -> list[dolfinx.fem.Function]:
        """The inertial displacement u and the straining displacement ũ (m) to write."""
        Xd = self.Xd
        self.body_u.x.array[:] = (
            (Xd + self.u.x.array.reshape(-1, 3)) @ self.rot.value - Xd
        ).ravel()
        return [self.u, self.body_u]

    def steps(self) -> MethodSteps:
        """This method's part of the shared time loop."""
        return MethodSteps(
            state=self.state,
            solver=self.solver,
            advance=self.advance,
            snapshot=self.snapshot,
            last=self.last,
            frame=self.frame,
        )


def run_coupled(model: DrivenBody, run: RunContext) -> None:
    """Run the coupled method on a driven body; results go to ``run.recorder``, ``run.fields``."""
    problem = InertialFrameProblem(model, run.options)
    march_driven_body(model, run, problem.steps(), problem.outputs())
