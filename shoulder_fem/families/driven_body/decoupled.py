"""Method #2, decoupled: rigid motion first, then small strains in the floating frame (eq. 13).

For a driven body the rigid motion is the hub's (prescribed, so the paper's step 1, eq. (10),
is the motion itself) and the floating frame turns with it. Part 2 solves the paper's eq. (13)
for the straining displacement ũ (body-frame components), linear elastic, clamped at the hub:

    ∫σ(ε(ũ)):ε(w) + ∫ρ(ũ̈ + 2Ω×ũ̇)·w + ∫ρ(a_G + Ω̇×GM + Ω×(Ω×GM))·w = 0,

GM taken at the rigid (undeformed) position as in the paper. ũ is written in body-frame
components, so its relative velocity and acceleration are plain time derivatives of those
components; the paper's Jaumann estimate v̇_B ≈ ṽ̇ − Ω×ṽ is what the same quantity looks like
when ṽ is carried in inertial components, and is not needed here. Time integration is the same
Newmark rule as the coupled method (average acceleration unless the scene asks for numerical
damping).

Variants (``decoupled_variant``): ``paper`` as above; ``spin-softening`` evaluates the Euler and
centrifugal terms at the strained position GM + ũ; ``stress-stiffening`` adds the geometric
stiffness of the centrifugal prestress ω²σ1 (σ1 from one static solve at ω = 1 rad/s).

The operator is A0 + ωG + ω²Q + ω̇E about the fixed spin axis: the four parts are assembled
once per Δt and combined per step (no re-assembly), and GMRES preconditioned by the LU of an
earlier operator absorbs the drift; a new factorization is made only when GMRES needs more than
a few iterations (``solver.factorizations`` in summary.json counts them: 1 for the runs here).
With ``quasi_static`` the ũ̈ and Coriolis terms are dropped.

After each step the run records the decoupling indicator (:class:`DecouplingIndicator`) and
the energies behind the spin-stiffness ratio (:func:`spin_stiffness_ratio`).
"""

from __future__ import annotations

import logging

import dolfinx
import numpy as np
import ufl
from mpi4py import MPI
from petsc4py import PETSc

from shoulder_fem.engine.fem import constant
from shoulder_fem.engine.mass import mass_properties
from shoulder_fem.engine.solver import NonlinearSolver
from shoulder_fem.families.base import RunContext
from shoulder_fem.families.driven_body.model import (
    BodyOutputs,
    DrivenBody,
    NewmarkState,
    boundary_reaction,
    clamp_dofs,
    dof_coordinates,
    march_driven_body,
    quadrature,
    vector_space,
)
from shoulder_fem.forms import kinematics, materials
from shoulder_fem.forms import virtual_power as vp

logger = logging.getLogger(__name__)


def run_decoupled(model: DrivenBody, run: RunContext) -> None:
    """Run the decoupled method on a driven body; results go to ``recorder`` and ``fields_dir``."""
    recorder = run.recorder
    monitor = run.monitor
    fields_dir = run.fields
    options = run.options
    mesh = model.mesh
    comm = mesh.comm
    V = vector_space(model)
    X = ufl.SpatialCoordinate(mesh)
    w = ufl.TestFunction(V)
    dx = ufl.Measure("dx", domain=mesh, metadata=quadrature(model))
    rho = model.density
    quasi_static = model.quasi_static
    variant = model.variant
    strained = variant in ("spin-softening", "stress-stiffening")
    axis = model.axis
    recorder.extra("decoupled_variant", variant)

    # Part 1: the rigid motion (the hub's) and the body's mass properties about G.
    props = mass_properties(mesh, rho, dx)
    mass, x_g, inertia = props.mass, props.centre, props.inertia
    recorder.extra("mass_kg", mass)
    recorder.extra("centre_of_mass_m", x_g)
    recorder.extra("inertia_tensor_kg_m2", inertia)
    omega = constant(mesh, np.zeros(3))  # body-frame angular velocity Ω = ω e
    domega = constant(mesh, np.zeros(3))  # body-frame angular acceleration Ω̇ = ω̇ e
    omega2 = constant(mesh, 0.0)  # ω², scales the centrifugal prestress
    a_g = constant(mesh, np.zeros(3))  # body-frame acceleration of G
    gm = X - constant(mesh, x_g)

    def set_rate(rate: float, rate_dot: float) -> None:
        omega.value[:], domega.value[:], omega2.value = rate * axis, rate_dot * axis, rate**2

    def set_frame(t: float) -> None:
        set_rate(model.motion.rate(t), model.motion.acceleration(t))
        wv, dwv = omega.value, domega.value
        a_g.value[:] = np.cross(dwv, x_g) + np.cross(wv, np.cross(wv, x_g))  # G turns about O

    # Part 2: eq. (13), linear, in the floating frame; the variants evaluate the rigid-frame
    # inertia at the strained position GM + ũ, and add the centrifugal prestress's geometric
    # stiffness.
    state = NewmarkState(V, "strain_displacement", model.numerical_damping)
    u = state.u
    nominal_dt = model.times[1] - model.times[0]
    dt = constant(mesh, nominal_dt)
    material = materials.LinearElastic(model.youngs_modulus, model.poisson_ratio)
    position = gm + u if strained else gm
    residual = (
        vp.internal_power_linear(material, u, w, dx)
        + vp.translational_inertia(rho, a_g, w, dx)
        + vp.euler_inertia(rho, domega, position, w, dx)
        + vp.centrifugal_inertia(rho, omega, position, w, dx)
    )
    if not quasi_static:
        residual += vp.relative_inertia(rho, state.acceleration(dt), w, dx)
        residual += vp.coriolis_inertia(rho, omega, state.velocity(dt), w, dx)
    dofs = clamp_dofs(model, V)
    bc = dolfinx.fem.dirichletbc(dolfinx.fem.Function(V), dofs)
    if variant == "stress-stiffening":
        sigma1 = unit_centrifugal_prestress(model, V, material, rho, gm, x_g, bc, dx, options)
        residual += vp.geometric_stiffness(omega2 * sigma1, u, w, dx)

    # The operator is A0 + ω G + ω² Q + ω̇ E (Coriolis in G; softening and stiffening in Q;
    # the strained Euler term in E). Each part is assembled once per Δt and combined per step;
    # GMRES around the factorization of an earlier operator absorbs the drift, re-factorizing
    # only when that stops paying (the solver turns preonly/cg into GMRES when it lags).
    rate_dependent = strained or not quasi_static
    opts = {"ksp_rtol": 1e-12, "ksp_max_it": 60, **(options or {})}
    parts: dict = {}
    last: dict = {"dt_key": 1.0, "operator": None, "rates": (0.0, 0.0)}

    def fill_operator(A) -> None:
        a0, g, q, e = parts[last["dt_key"]]
        rate, rate_dot = last["rates"]
        a0.copy(A, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
        for coefficient, mat in ((rate, g), (rate**2, q), (rate_dot, e)):
            if coefficient != 0.0:
                A.axpy(coefficient, mat, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)

    solver = NonlinearSolver(
        residual,
        u,
        [bc],
        name="decoupled",
        linear=True,
        options=opts,
        form_compiler_params=quadrature(model),
        operator=fill_operator if rate_dependent else None,
        lagged_factorization=rate_dependent,
    )

    def operator_parts(dt_key) -> None:
        """Assemble A0, G, Q, E at this Δt (J is affine in ω̇ and quadratic in ω)."""
        if dt_key in parts:
            return
        saved = (omega.value.copy(), domega.value.copy(), float(omega2.value))

        def jac(rate: float, rate_dot: float):
            set_rate(rate, rate_dot)
            return solver.assemble_jacobian()

        a0, plus, minus, e = jac(0.0, 0.0), jac(1.0, 0.0), jac(-1.0, 0.0), jac(0.0, 1.0)
        same = PETSc.Mat.Structure.SAME_NONZERO_PATTERN
        g = plus.copy()
        g.axpy(-1.0, minus, structure=same)
        g.scale(0.5)  # G = (J(1) − J(−1))/2
        q = plus
        q.axpy(1.0, minus, structure=same)
        q.scale(0.5)
        q.axpy(-1.0, a0, structure=same)  # Q = (J(1) + J(−1))/2 − A0
        e.axpy(-1.0, a0, structure=same)  # E = J(ω̇ = 1) − A0
        minus.destroy()
        parts[dt_key] = (a0, g, q, e)
        omega.value[:], domega.value[:], omega2.value = saved

    residual_form = dolfinx.fem.form(residual, form_compiler_params=quadrature(model))
    outputs = BodyOutputs(model, u, material.stress(kinematics.linear_strain(u)))
    Xd = dof_coordinates(V)
    indicator = DecouplingIndicator(mesh, V, rho, gm, dx, mass, x_g, inertia)
    indicator.set_motion(
        np.array([model.motion.omega_vector(t) for t in model.times]),
        np.array([model.motion.domega_vector(t) for t in model.times]),
    )

    def advance(t0: float, t1: float) -> None:
        h = t1 - t0
        dt.value = h
        set_frame(t1)
        # The operator depends on Δt, ω and ω̇ only (Δt to 1e-9 relative: linspace round-off).
        last["dt_key"] = round(h / nominal_dt, 9)
        last["rates"] = (model.motion.rate(t1), model.motion.acceleration(t1))
        key = (last["dt_key"], *last["rates"]) if rate_dependent else (last["dt_key"],)
        if key != last["operator"]:
            if rate_dependent:
                operator_parts(last["dt_key"])
            solver.operator_changed()
            last["operator"] = key
        solver.solve(step=f"t = {t1:.6g} s")
        last["reaction"], last["moment"] = boundary_reaction(residual_form, dofs, comm, Xd)
        state.advance(h, dynamic=not quasi_static)

    inertial_u = dolfinx.fem.Function(V, name="displacement")

    def snapshot(t: float) -> list:
        r = model.motion.rotation(t)  # x = R (X + ũ): the inertial displacement for ParaView
        inertial_u.x.array[:] = ((Xd + u.x.array.reshape(-1, 3)) @ r.T - Xd).ravel()
        return [inertial_u, u]

    # What the linear part neglects of eq. (13) itself: the centrifugal terms on ũ against the
    # elastic ones, Ω²∫ρ|ũ⊥|² / ∫σ(ũ):ε(ũ) — a Rayleigh-quotient estimate of (Ω/ω)² for the
    # current deformation shape ω.
    spin_energy = dolfinx.fem.form(rho * ufl.dot(ufl.cross(omega, u), ufl.cross(omega, u)) * dx)
    strain_energy = dolfinx.fem.form(
        ufl.inner(material.stress(kinematics.linear_strain(u)), kinematics.linear_strain(u)) * dx
    )

    def total(form) -> float:
        return comm.allreduce(dolfinx.fem.assemble_scalar(form), op=MPI.SUM)

    def record_indicator(t: float) -> None:
        value = indicator.evaluate(
            state, model.motion.omega_vector(t), model.motion.domega_vector(t)
        )
        recorder.add_series_point("decoupling_indicator", t, value, "s", "1")
        recorder.add_series_point("spin_energy", t, total(spin_energy), "s", "J")
        recorder.add_series_point("strain_energy", t, total(strain_energy), "s", "J")
        if value > INDICATOR_WARNING and not last.get("warned"):
            last["warned"] = True
            logger.warning(
                "t = %.4g s: decoupling indicator %.3g > %.3g: the straining motion's share of "
                "the momentum balance is no longer small; compare with the coupled method",
                t,
                value,
                INDICATOR_WARNING,
            )

    try:
        march_driven_body(
            model,
            recorder,
            monitor,
            fields_dir,
            state,
            solver,
            advance,
            outputs,
            snapshot,
            last,
            extra_record=record_indicator,
        )
    finally:
        series = recorder.series.get("decoupling_indicator", {}).get("y", [0.0])
        recorder.set_probe("max_decoupling_indicator", float(max(series)), "1")
        recorder.set_probe("max_spin_stiffness_ratio", spin_stiffness_ratio(recorder), "1")
        for mats in parts.values():
            for mat in mats:
                mat.destroy()


def spin_stiffness_ratio(recorder) -> float:
    """Largest Ω²∫ρ|ũ⊥|² / ∫σ:ε over the steps whose strain energy is ≥ 1 % of its maximum.

    Small: the centrifugal terms the paper's linear eq. (13) leaves out are negligible. Near or
    above 1: the spin reaches the deformation's own frequency and the variants part ways.
    """
    spin = np.asarray(recorder.series.get("spin_energy", {}).get("y", []), dtype=float)
    elastic = np.asarray(recorder.series.get("strain_energy", {}).get("y", []), dtype=float)
    if not len(elastic) or not np.isfinite(elastic).all() or elastic.max() <= 0.0:
        return 0.0
    keep = elastic >= 0.01 * elastic.max()
    return float(np.max(spin[keep] / elastic[keep]))


#: Above this value of the decoupling indicator a warning is logged.
INDICATOR_WARNING = 0.05


def unit_centrifugal_prestress(model, V, material, rho, gm, x_g, bc, dx, options):
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


class DecouplingIndicator:
    """The terms step 1 of the decoupling neglects (paper eqs. 11–12), relative to those kept.

    Neglected, in the body frame: the force ∫ρ ṽ̇ + 2Ω × ∫ρ ṽ, and the moment about G
    ∫ρ GM × ṽ̇ + 2∫ρ GM × (Ω × ṽ) + ΔI Ω̇ + Ω × ΔI Ω with ΔI the first-order change of I_G due
    to ũ. Kept: m a_G and I_G Ω̇ + Ω × I_G Ω, measured by the scales m(|a_G| + r_g(|Ω̇| + |Ω|²))
    and ‖I_G‖(|Ω̇| + |Ω|²) (r_g the radius of gyration) so that a steady spin about a principal
    axis, whose kept moment vanishes, still has a finite reference; each scale is its largest
    value over the whole rigid motion (known from part 1 before part 2 starts), so the start
    from rest does not divide by ~0. The indicator is the larger of the two ratios
    (dimensionless); 0 for a body that never moves.

    All the integrals are linear in the fields: 12 vectors (∫ρ e_k·w and ∫ρ GM_i e_j·w) are
    assembled once and each evaluation is a few dot products.
    """

    def __init__(self, mesh, V, rho, gm, dx, mass, x_g, inertia):
        w = ufl.TestFunction(V)
        direction = constant(mesh, np.zeros(3))
        weight = constant(mesh, np.zeros(3))
        form = dolfinx.fem.form(rho * ufl.dot(weight, gm) * ufl.dot(direction, w) * dx)
        form_mass = dolfinx.fem.form(rho * ufl.dot(direction, w) * dx)
        self.comm = mesh.comm
        n_owned = V.dofmap.index_map.size_local * V.dofmap.index_map_bs
        self._n = n_owned
        eye = np.eye(3)

        def assemble(f) -> np.ndarray:
            vec = dolfinx.fem.petsc.assemble_vector(f)
            vec.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
            out = vec.array[:n_owned].copy()
            vec.destroy()
            return out

        self._m = []
        for k in range(3):
            direction.value[:] = eye[k]
            self._m.append(assemble(form_mass))
        self._t = [[None] * 3 for _ in range(3)]
        for i in range(3):
            weight.value[:] = eye[i]
            for j in range(3):
                direction.value[:] = eye[j]
                self._t[i][j] = assemble(form)
        self.mass = mass
        self.x_g = np.asarray(x_g)
        self.inertia = np.asarray(inertia)
        self.inertia_norm = float(np.linalg.norm(self.inertia, 2))
        self.r_g = float(np.sqrt(self.inertia_norm / mass))
        self._force_ref = 0.0
        self._moment_ref = 0.0

    def set_motion(self, omegas: np.ndarray, domegas: np.ndarray) -> None:
        """Reference scales from the whole rigid motion (part 1 is known before part 2).

        Args:
            omegas: body-frame angular velocities at the output times, shape (n, 3), rad/s.
            domegas: body-frame angular accelerations at the same times, rad/s².
        """
        spin = np.linalg.norm(domegas, axis=1) + np.linalg.norm(omegas, axis=1) ** 2
        a_g = np.cross(domegas, self.x_g) + np.cross(omegas, np.cross(omegas, self.x_g))
        self._force_ref = float(np.max(self.mass * (np.linalg.norm(a_g, axis=1) + self.r_g * spin)))
        self._moment_ref = float(np.max(self.inertia_norm * spin))

    def _first(self, field) -> np.ndarray:
        local = np.array([m @ field for m in self._m])
        return self.comm.allreduce(local, op=MPI.SUM)

    def _second(self, field) -> np.ndarray:
        local = np.array([[self._t[i][j] @ field for j in range(3)] for i in range(3)])
        return self.comm.allreduce(local, op=MPI.SUM)

    def evaluate(self, state, omega: np.ndarray, domega: np.ndarray) -> float:
        """The indicator for the state at the end of the last step (collective)."""
        n = self._n
        u, v, a = (f.x.array[:n] for f in (state.u_n, state.v_n, state.a_n))
        force = self._first(a) + 2.0 * np.cross(omega, self._first(v))
        ta, tv, tu = self._second(a), self._second(v), self._second(u)
        eps = np.array(
            [
                [[float((i - j) * (j - k) * (k - i) / 2) for k in range(3)] for j in range(3)]
                for i in range(3)
            ]
        )
        moment = np.einsum("kij,ij->k", eps, ta)  # ∫ρ GM × ṽ̇
        moment += 2.0 * (omega * np.trace(tv) - tv.T @ omega)  # 2∫ρ GM × (Ω × ṽ)
        delta_i = 2.0 * np.trace(tu) * np.eye(3) - (tu + tu.T)
        moment += delta_i @ domega + np.cross(omega, delta_i @ omega)
        if self._force_ref == 0.0 or self._moment_ref == 0.0:
            return 0.0
        return float(
            max(np.linalg.norm(force) / self._force_ref, np.linalg.norm(moment) / self._moment_ref)
        )
