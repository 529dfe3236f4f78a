"""Method #2, decoupled: rigid motion first, then small strains in the floating frame (eq. 13).

For a driven body the rigid motion is the hub's (prescribed, so the paper's step 1, eq. (10),
is the motion itself) and the floating frame turns with it. Part 2 solves the paper's eq. (13)
for the straining displacement ũ (body-frame components), linear elastic, clamped at the hub:

    ∫σ(ε(ũ)):ε(w) + ∫ρ(ũ̈ + 2Ω×ũ̇)·w + ∫ρ(a_G + Ω̇×GM + Ω×(Ω×GM))·w = 0,

GM taken at the rigid (undeformed) position as in the paper. ũ is written in body-frame
components, so its relative velocity and acceleration are plain time derivatives of those
components; the paper's Jaumann estimate v̇_B ≈ ṽ̇ − Ω×ṽ is what the same quantity looks like
when ṽ is carried in inertial components, and is not needed here. Time integration is the same
Newmark average-acceleration rule as the coupled method. The operator K + M/(βΔt²) + Coriolis
changes only when Ω or Δt does: it is re-assembled and re-factorized then, and the same LU
serves every step at constant spin. With ``quasi_static`` the ũ̈ and Coriolis terms are dropped
and one factorization serves the whole run.
"""

from __future__ import annotations

import logging

import dolfinx
import numpy as np
import ufl
from mpi4py import MPI
from petsc4py import PETSc

from ..driven_body import (
    BodyOutputs,
    DrivenBody,
    NewmarkState,
    boundary_reaction,
    clamp_dofs,
    constant,
    dof_coordinates,
    march_driven_body,
    quadrature,
    vector_space,
)
from ..forms import kinematics, materials, rigid_body
from ..forms import virtual_power as vp
from ..solver import NonlinearSolver

logger = logging.getLogger(__name__)


def centre_of_mass(mesh, rho: float, dx) -> tuple[float, np.ndarray]:
    """Mass (kg) and centre of mass (m) of a body of uniform density (collective)."""
    X = ufl.SpatialCoordinate(mesh)

    def total(form) -> float:
        return mesh.comm.allreduce(dolfinx.fem.assemble_scalar(dolfinx.fem.form(form)), MPI.SUM)

    m = total(rigid_body.mass(rho, dx))
    return m, np.array([total(f) for f in rigid_body.first_moment(rho, X, dx)]) / m


def run_driven_body(model: DrivenBody, recorder, monitor, fields_dir, options=None) -> None:
    """Run the decoupled method on a driven body; results go to ``recorder`` and ``fields_dir``."""
    mesh = model.mesh
    comm = mesh.comm
    V = vector_space(model)
    X = ufl.SpatialCoordinate(mesh)
    w = ufl.TestFunction(V)
    dx = ufl.Measure("dx", domain=mesh, metadata=quadrature(model))
    rho = model.density
    quasi_static = model.quasi_static

    # Part 1: the rigid motion (the hub's) and the body's mass properties about G.
    mass, x_g = centre_of_mass(mesh, rho, dx)
    recorder.extra("mass_kg", mass)
    recorder.extra("centre_of_mass_m", x_g)
    omega = constant(mesh, np.zeros(3))  # body-frame angular velocity
    domega = constant(mesh, np.zeros(3))  # body-frame angular acceleration
    a_g = constant(mesh, np.zeros(3))  # body-frame acceleration of G
    gm = X - constant(mesh, x_g)

    def set_frame(t: float) -> None:
        wv, dwv = model.motion.omega_vector(t), model.motion.domega_vector(t)
        omega.value[:], domega.value[:] = wv, dwv
        a_g.value[:] = np.cross(dwv, x_g) + np.cross(wv, np.cross(wv, x_g))  # G turns about O

    # Part 2: eq. (13), linear, in the floating frame.
    state = NewmarkState(V, "strain_displacement")
    u = state.u
    nominal_dt = model.times[1] - model.times[0]
    dt = constant(mesh, nominal_dt)
    material = materials.LinearElastic(model.youngs_modulus, model.poisson_ratio)
    residual = vp.internal_power_linear(material, u, w, dx) + vp.rigid_frame_inertia(
        rho, a_g, omega, domega, gm, w, dx
    )
    if not quasi_static:
        residual += vp.relative_inertia(rho, state.acceleration(dt), w, dx)
        residual += vp.coriolis_inertia(rho, omega, state.velocity(dt), w, dx)
    last: dict = {"dt_key": 1.0}
    dofs = clamp_dofs(model, V)
    zero = dolfinx.fem.Function(V)
    bc = dolfinx.fem.dirichletbc(zero, dofs)
    # The Coriolis term makes the operator non-symmetric and lets it drift with Ω: GMRES,
    # preconditioned by the factorization of an earlier operator until that stops paying
    # (the solver turns preonly/cg into GMRES when it lags the factorization).
    opts = {"ksp_rtol": 1e-12, "ksp_max_it": 60, **(options or {})}
    # Δt key → [A0, G_x, G_y, G_z]: A(Ω) = A0 + Σ Ω_i G_i, each G_i assembled the first time
    # Ω_i ≠ 0 (a spin about z needs G_z only).
    parts: dict = {}

    def fill_operator(A) -> None:
        a0, *gs = parts[last["dt_key"]]
        a0.copy(A, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
        for value, g in zip(omega.value, gs, strict=True):
            if value != 0.0:
                A.axpy(value, g, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)

    solver = NonlinearSolver(
        residual,
        u,
        [bc],
        name="decoupled",
        linear=True,
        options=opts,
        form_compiler_params=quadrature(model),
        operator=None if quasi_static else fill_operator,
        lagged_factorization=not quasi_static,
    )

    def operator_parts(dt_key) -> None:
        """Assemble A0 (Ω = 0) and the Coriolis matrices per unit Ω_i still missing at this Δt."""
        saved = omega.value.copy()
        if dt_key not in parts:
            omega.value[:] = 0.0
            parts[dt_key] = [solver.assemble_jacobian(), None, None, None]
        entry = parts[dt_key]
        for i in range(3):
            if saved[i] != 0.0 and entry[i + 1] is None:
                omega.value[:] = np.eye(3)[i]
                g = solver.assemble_jacobian()
                g.axpy(-1.0, entry[0], structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
                entry[i + 1] = g
        omega.value[:] = saved

    residual_form = dolfinx.fem.form(residual, form_compiler_params=quadrature(model))
    outputs = BodyOutputs(model, u, material.stress(kinematics.linear_strain(u)))
    Xd = dof_coordinates(V)
    last["operator"] = None

    def advance(t0: float, t1: float) -> None:
        h = t1 - t0
        dt.value = h
        set_frame(t1)
        # The operator depends on Δt and Ω only (Δt to 1e-9 relative: linspace round-off).
        last["dt_key"] = round(h / nominal_dt, 9)
        key = (last["dt_key"],) + (() if quasi_static else tuple(omega.value))
        if key != last["operator"]:
            if not quasi_static:
                operator_parts(last["dt_key"])
            solver.operator_changed()
            last["operator"] = key
        solver.solve(step=f"t = {t1:.6g} s")
        last["reaction"] = boundary_reaction(residual_form, dofs, comm)
        state.advance(h, dynamic=not quasi_static)

    inertial_u = dolfinx.fem.Function(V, name="displacement")

    def snapshot(t: float) -> list:
        r = model.motion.rotation(t)  # x = R (X + ũ): the inertial displacement for ParaView
        inertial_u.x.array[:] = ((Xd + u.x.array.reshape(-1, 3)) @ r.T - Xd).ravel()
        return [inertial_u, u]

    try:
        march_driven_body(
            model, recorder, monitor, fields_dir, state, solver, advance, outputs, snapshot, last
        )
    finally:
        for entry in parts.values():
            for mat in entry:
                if mat is not None:
                    mat.destroy()
