"""Method #2 on the driven body, decoupled: rigid motion first, then small strains in its frame.

Owns :class:`FloatingFrameProblem` — the straining displacement ũ of eq. (13) in the floating
frame (:mod:`.frame`), with the scene's variant (:mod:`.variants`) and the rate-split operator
(:mod:`.rate_operator`) — and :func:`run_decoupled`, which marches it with the time loop both
methods share and records the decoupling indicator (:mod:`.indicator`).
"""

from __future__ import annotations

import dolfinx
import ufl

from shoulder_fem.engine.fem import constant
from shoulder_fem.engine.mass import mass_properties
from shoulder_fem.engine.newmark import NewmarkState
from shoulder_fem.engine.solver import NonlinearSolver
from shoulder_fem.families.base import RunContext, SolverOptions
from shoulder_fem.families.driven_body.frame import FloatingFrame
from shoulder_fem.families.driven_body.indicator import (
    DecouplingRecord,
)
from shoulder_fem.families.driven_body.model import (
    DrivenBody,
    clamp_dofs,
    dof_coordinates,
    quadrature,
    vector_space,
)
from shoulder_fem.families.driven_body.outputs import BodyOutputs, LastStep, boundary_reaction
from shoulder_fem.families.driven_body.rate_operator import RateOperator
from shoulder_fem.families.driven_body.stepping import MethodSteps, march_driven_body
from shoulder_fem.families.driven_body.variants import (
    STRAINED_VARIANTS,
    floating_frame_residual,
    unit_centrifugal_prestress,
)
from shoulder_fem.forms import kinematics, materials
from shoulder_fem.forms import virtual_power as vp

__all__ = [
    "FloatingFrameProblem",
    "run_decoupled",
]


class FloatingFrameProblem:
    """Eq. (13) for ũ (body-frame components), linear elastic, clamped at the hub.

    One linear solve per Newmark step with the operator of :class:`RateOperator`; with
    ``quasi_static`` the ũ̈ and Coriolis terms are dropped.

    Args:
        model: the driven body.
        frame: the floating frame (the hub's motion).
        dx: the volume measure.
        options: PETSc options overriding the solvers' defaults.
    """

    def __init__(
        self,
        model: DrivenBody,
        frame: FloatingFrame,
        dx: ufl.Measure,
        options: SolverOptions | None = None,
    ):
        self.model, self.frame = model, frame
        mesh = model.mesh
        V = vector_space(model)
        w = ufl.TestFunction(V)
        self.state = NewmarkState(V, "strain_displacement", model.numerical_damping)
        u = self.u = self.state.u
        nominal_dt = model.times[1] - model.times[0]
        self.dt = constant(mesh, nominal_dt)
        self.material = materials.LinearElastic(model.youngs_modulus, model.poisson_ratio)
        residual = floating_frame_residual(model, frame, self.state, self.dt, self.material, w, dx)
        self.dofs = clamp_dofs(model, V)
        bc = dolfinx.fem.dirichletbc(dolfinx.fem.Function(V), self.dofs)
        if model.variant == "stress-stiffening":
            sigma1 = unit_centrifugal_prestress(
                model, V, self.material, model.density, frame.gm, frame.x_g, bc, dx, options
            )
            residual += vp.geometric_stiffness(frame.omega2 * sigma1, u, w, dx)
        # GMRES around the factorization of an earlier operator absorbs the drift, re-factorizing
        # only when that stops paying (the solver turns preonly/cg into GMRES when it lags).
        rate_dependent = model.variant in STRAINED_VARIANTS or not model.quasi_static
        self.operator = RateOperator(frame, nominal_dt, rate_dependent)
        self.solver = NonlinearSolver(
            residual,
            u,
            [bc],
            name="decoupled",
            linear=True,
            options={"ksp_rtol": 1e-12, "ksp_max_it": 60, **(options or {})},
            form_compiler_params=quadrature(model),
            operator=self.operator.fill if rate_dependent else None,
            lagged_factorization=rate_dependent,
        )
        self.residual_form = dolfinx.fem.form(residual, form_compiler_params=quadrature(model))
        self.Xd = dof_coordinates(V)
        self.inertial_u = dolfinx.fem.Function(V, name="displacement")
        self.last = LastStep()

    def outputs(self) -> BodyOutputs:
        """Body-frame measures of ũ and its linear elastic stress."""
        return BodyOutputs(
            self.model, self.u, self.material.stress(kinematics.linear_strain(self.u))
        )

    def advance(self, t0: float, t1: float) -> None:
        """Solve the step from ``t0`` to ``t1`` (s); store the clamp reaction in :attr:`last`."""
        model = self.model
        h = t1 - t0
        self.dt.value = h
        self.frame.move_to(t1)
        self.operator.select(self.solver, h, model.motion.rate(t1), model.motion.acceleration(t1))
        self.solver.solve(step=f"t = {t1:.6g} s")
        self.last.reaction, self.last.moment = boundary_reaction(
            self.residual_form, self.dofs, model.mesh.comm, self.Xd
        )
        self.state.advance(h, dynamic=not model.quasi_static)

    def snapshot(self, t: float) -> list[dolfinx.fem.Function]:
        """The inertial displacement (x = R (X + ũ), for ParaView) and ũ (m) to write."""
        Xd = self.Xd
        r = self.model.motion.rotation(t)
        self.inertial_u.x.array[:] = ((Xd + self.u.x.array.reshape(-1, 3)) @ r.T - Xd).ravel()
        return [self.inertial_u, self.u]

    def steps(self, extra_record=None) -> MethodSteps:
        """This method's part of the shared time loop (``extra_record(t)`` after each step)."""
        return MethodSteps(
            state=self.state,
            solver=self.solver,
            advance=self.advance,
            snapshot=self.snapshot,
            last=self.last,
            extra_record=extra_record,
        )


def run_decoupled(model: DrivenBody, run: RunContext) -> None:
    """Run the decoupled method on a driven body; results go to ``run.recorder``, ``run.fields``."""
    recorder = run.recorder
    dx = ufl.Measure("dx", domain=model.mesh, metadata=quadrature(model))
    recorder.extra("decoupled_variant", model.variant)
    # Part 1: the rigid motion (the hub's) and the body's mass properties about G.
    props = mass_properties(model.mesh, model.density, dx)
    recorder.extra("mass_kg", props.mass)
    recorder.extra("centre_of_mass_m", props.centre)
    recorder.extra("inertia_tensor_kg_m2", props.inertia)
    frame = FloatingFrame(model, props.centre)
    # Part 2: eq. (13), linear, in the floating frame.
    problem = FloatingFrameProblem(model, frame, dx, run.options)
    indicator = DecouplingRecord(model, recorder, problem.state, problem.material, frame, props, dx)
    try:
        march_driven_body(model, run, problem.steps(indicator.record), problem.outputs())
    finally:
        indicator.finish()
        problem.operator.destroy()
