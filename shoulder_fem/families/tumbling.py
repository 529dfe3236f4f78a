"""The ``tumbling-body`` family: a free flexible body spinning near its intermediate axis.

A box of uniform density with no support and no load spins about its intermediate principal axis
(y) with a small component about the minor axis (x): the rotation is unstable (the
"tennis-racket" or Dzhanibekov effect) and the body flips periodically, its body-frame angular
momentum component along y swinging between +|L| and −|L|. :func:`run_coupled` runs the
floating-frame solver of eq. (14), :func:`run_decoupled` the paper's steps 1–3; both report the
same measures (:class:`Reporter`).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import dolfinx
import dolfinx.fem.petsc as fem_petsc
import numpy as np
import ufl
from mpi4py import MPI

from shoulder_fem.engine.bordered import BorderedSolver, assemble_owned
from shoulder_fem.engine.fem import constant
from shoulder_fem.engine.floating import FloatingBody
from shoulder_fem.engine.floating_forms import mean_axes_forms
from shoulder_fem.engine.mass import MassProperties, mass_properties
from shoulder_fem.engine.motion_measures import MotionMeasures
from shoulder_fem.engine.newmark import NewmarkState
from shoulder_fem.engine.rigid import NewtonEuler, RigidState
from shoulder_fem.engine.solver import ConvergenceError, SolveStats, StepperStats, march, time_grid
from shoulder_fem.families.base import Family, RunContext
from shoulder_fem.families.driven_body.indicator import INDICATOR_WARNING, DecouplingIndicator
from shoulder_fem.forms import kinematics, materials
from shoulder_fem.forms import virtual_power as vp
from shoulder_fem.io.fields import FieldWriter
from shoulder_fem.meshes.box import build_box
from shoulder_fem.scene import Scene, SceneError

logger = logging.getLogger(__name__)

#: Body axis the flip indicator follows (the intermediate principal axis of the box).
FLIP_AXIS = 1


@dataclass
class TumblingBody:
    """Everything both methods need to run a tumbling-body scene (SI units)."""

    scene: Scene
    level: str
    mesh: dolfinx.mesh.Mesh
    V: dolfinx.fem.FunctionSpace
    degree: int
    density: float
    youngs_modulus: float
    poisson_ratio: float
    lengths: tuple[float, float, float]
    omega0: np.ndarray
    times: np.ndarray
    field_times: np.ndarray
    relaxed_start: bool


def build(
    scene: Scene, level: str | None, comm: MPI.Comm, method: str | None = None
) -> TumblingBody:
    """Check the scene's parameters together and build the mesh of ``level``."""
    p = scene.values()
    lv = scene.level(level)
    lengths = (p["length_x"], p["length_y"], p["length_z"])
    if not lengths[0] > lengths[1] > lengths[2]:
        raise SceneError(
            f"{scene.where('length_x', 'length_y', 'length_z')}: the flip needs distinct "
            f"principal moments, length_x > length_y > length_z (got {lengths} m)"
        )
    if p["time_step"] > p["end_time"]:
        raise SceneError(
            f"{scene.where('time_step', 'end_time')}: time_step = {p['time_step']} s exceeds "
            f"end_time = {p['end_time']} s"
        )
    for key in ("degree", "n_x", "n_y", "n_z"):
        if key not in lv or int(lv[key]) < 1:
            raise SceneError(f"{scene.source}: levels.{level}.{key} must be a positive integer")
    times, field_times = time_grid(p["end_time"], p["time_step"], int(p["field_outputs"]))
    mesh = build_box(comm, lengths, (int(lv["n_x"]), int(lv["n_y"]), int(lv["n_z"])))
    degree = int(lv["degree"])
    omega0 = p["spin_rate"] * np.array([p["perturbation"], 1.0, 0.0])
    return TumblingBody(
        scene=scene,
        level=level or scene.default_level,
        mesh=mesh,
        V=dolfinx.fem.VectorFunctionSpace(mesh, ("Lagrange", degree)),
        degree=degree,
        density=p["density"],
        youngs_modulus=p["youngs_modulus"],
        poisson_ratio=p["poisson_ratio"],
        lengths=lengths,
        omega0=omega0,
        times=times,
        field_times=field_times,
        relaxed_start=bool(p["relaxed_start"]),
    )


def dofs(model: TumblingBody) -> int:
    """Global number of straining-displacement DOFs (the 6 frame DOFs not counted)."""
    return model.V.dofmap.index_map.size_global * model.V.dofmap.index_map_bs


# --------------------------------------------------------------------------------------------
# Measures shared by both methods
# --------------------------------------------------------------------------------------------


def flip_indicator(R: np.ndarray, L_g: np.ndarray) -> float:
    """(Rᵀ L_G)·e_y/|L_G|: +1 spinning about +y, −1 after a flip (dimensionless)."""
    return float((R.T @ L_g)[FLIP_AXIS] / np.linalg.norm(L_g))


def flip_period(t: np.ndarray, indicator: np.ndarray) -> float:
    """Twice the mean interval (s) between zero crossings of the indicator (linear interpolation).

    Returns NaN with fewer than two crossings.
    """
    t, y = np.asarray(t, dtype=float), np.asarray(indicator, dtype=float)
    idx = np.nonzero(np.sign(y[:-1]) * np.sign(y[1:]) < 0)[0]
    crossings = t[idx] - y[idx] * (t[idx + 1] - t[idx]) / (y[idx + 1] - y[idx])
    if len(crossings) < 2:
        return math.nan
    return float(2.0 * np.mean(np.diff(crossings)))


def rigid_flip_period(
    mass: float, inertia: np.ndarray, omega0: np.ndarray, end_time: float, dt: float
) -> float:
    """Flip period (s) of the rigid body, integrated by NewtonEuler with step ``dt`` (s)."""
    integrator = NewtonEuler(mass, inertia)
    n = int(math.ceil(end_time / dt))
    states = integrator.integrate(RigidState(omega=omega0), end_time / n, n)
    t = np.array([s.t for s in states])
    y = np.array([flip_indicator(s.R, integrator.angular_momentum(s)) for s in states])
    return flip_period(t, y)


class Reporter:
    """Records the series of both methods and the probes at the end (collective).

    The series, from the same functionals for both methods: the kinetic energy, |L|, the linear
    momentum, the rigid-equivalent body-frame angular velocity Ω = I_G⁻¹ Rᵀ L_G, the flip
    indicator (Rᵀ L_G)·e_y/|L_G| and the largest von Mises stress. The probes: ``flip_period``
    (twice the mean interval between zero crossings of the indicator), ``flip_period_rigid``
    (the same measure on a rigid body integrated by NewtonEuler with a step ten times smaller),
    ``energy_drift`` and ``angular_momentum_drift`` (largest relative deviations from t = 0).
    """

    def __init__(self, model: TumblingBody, recorder, inertia: np.ndarray, mass: float):
        self.model, self.recorder = model, recorder
        self.inertia_inv = np.linalg.inv(inertia)
        self.inertia, self.mass = inertia, mass
        self.t: list[float] = []
        self.energy: list[float] = []
        self.L: list[np.ndarray] = []
        self.P: list[np.ndarray] = []
        self.indicator: list[float] = []

    def record(
        self,
        t: float,
        R: np.ndarray,
        x_g: np.ndarray,
        kinetic: float,
        strain: float,
        P: np.ndarray,
        L: np.ndarray,
        von_mises: float,
    ) -> None:
        """One point of every series; ``L`` about the origin, ``x_g`` the centre of mass."""
        rec = self.recorder
        L_g = L - np.cross(x_g, P)
        omega = self.inertia_inv @ (R.T @ L_g)
        indicator = flip_indicator(R, L_g)
        self.t.append(t)
        self.energy.append(kinetic + strain)
        self.L.append(L_g)
        self.P.append(P)
        self.indicator.append(indicator)
        rec.add_series_point("kinetic_energy", t, kinetic, "s", "J")
        rec.add_series_point("strain_energy", t, strain, "s", "J")
        rec.add_series_point("total_energy", t, kinetic + strain, "s", "J")
        rec.add_series_point("angular_momentum", t, float(np.linalg.norm(L_g)), "s", "kg m^2/s")
        rec.add_series_point("linear_momentum", t, float(np.linalg.norm(P)), "s", "kg m/s")
        for i, name in enumerate("xyz"):
            rec.add_series_point(f"omega_body_{name}", t, float(omega[i]), "s", "rad/s")
        rec.add_series_point("flip_indicator", t, indicator, "s", "1")
        angle = float(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)))
        rec.add_series_point("rotation_angle", t, angle, "s", "rad")
        rec.add_series_point("max_von_mises", t, von_mises, "s", "Pa")

    def finish(self) -> None:
        """Probes from the recorded series and the rigid reference."""
        rec, model = self.recorder, self.model
        e = np.array(self.energy)
        L = np.array(self.L)
        P = np.array(self.P)
        t = np.array(self.t)
        rec.set_probe("flip_period", flip_period(t, np.array(self.indicator)), "s")
        dt = model.times[1] - model.times[0]
        rec.set_probe(
            "flip_period_rigid",
            rigid_flip_period(self.mass, self.inertia, model.omega0, model.times[-1], dt / 10),
            "s",
        )
        rec.set_probe("energy_drift", float(np.max(np.abs(e - e[0])) / e[0]), "1")
        rec.set_probe(
            "angular_momentum_drift",
            float(np.max(np.linalg.norm(L - L[0], axis=1)) / np.linalg.norm(L[0])),
            "1",
        )
        rec.set_probe(
            "linear_momentum_drift", float(np.max(np.linalg.norm(P - P[0], axis=1))), "kg m/s"
        )
        rec.set_probe("final_time", float(t[-1]), "s")
        rec.set_probe("final_flip_indicator", float(self.indicator[-1]), "1")
        rec.set_probe("peak_von_mises", float(np.max(rec.series["max_von_mises"]["y"])), "Pa")


def quasi_static_straining(model: TumblingBody, omega: np.ndarray) -> np.ndarray:
    """Linear quasi-static straining ũ (m) of the body spinning at Ω (body frame, rad/s).

    With ``relaxed_start`` (the default) both methods start from this straining instead of
    ũ = 0: a sudden centrifugal load on an unstrained body would ring its elastic modes, whose
    periods (~1 ms at E = 15 MPa) the time step does not resolve.

    Eq. (13) without the relative-inertia and Coriolis terms, with Ω̇ from Euler's torque-free
    equation, ∫σ(ε(ũ)):ε(w) + ∫ρ(Ω̇ × Y + Ω × (Ω × Y))·w = 0, and the mean-axes conditions.
    The load is self-equilibrated, so the free problem has a solution; the stiffness is
    shifted by s M with s = 1e-8 E/(ρ ℓ²) (ℓ the largest side) so that MUMPS can factorize it,
    which changes the elastic response by ~1e-8 relative and the rigid modes not at all (the
    load has no rigid-mode component; the frame conditions pin them).

    Returns:
        ũ as the local + ghost entries of the blocked array of ``model.V``.
    """
    mesh, V, rho = model.mesh, model.V, model.density
    qd = 2 * model.degree
    dx = ufl.Measure("dx", domain=mesh, metadata={"quadrature_degree": qd})
    fcp = {"quadrature_degree": qd}
    props = mass_properties(mesh, rho, dx)
    domega = np.linalg.solve(props.inertia, -np.cross(omega, props.inertia @ omega))
    material = materials.LinearElastic(model.youngs_modulus, model.poisson_ratio)
    Y = ufl.SpatialCoordinate(mesh) - ufl.as_vector(props.centre.tolist())
    u, w = ufl.TrialFunction(V), ufl.TestFunction(V)
    shift = 1e-8 * model.youngs_modulus / (rho * max(model.lengths) ** 2)
    a = vp.internal_power_linear(material, u, w, dx) + shift * rho * ufl.dot(u, w) * dx
    zero = ufl.as_vector([0.0, 0.0, 0.0])
    load = vp.rigid_frame_inertia(
        rho, zero, ufl.as_vector(omega.tolist()), ufl.as_vector(domega.tolist()), Y, w, dx
    )
    A = fem_petsc.assemble_matrix(dolfinx.fem.form(a, form_compiler_params=fcp))
    A.assemble()

    def vector(form) -> np.ndarray:
        return assemble_owned(dolfinx.fem.form(form, form_compiler_params=fcp))

    C = [vector(f) for f in mean_axes_forms(rho, Y, w, dx)]
    solver = BorderedSolver(mesh.comm, A, "tumbling_static")
    y, _ = solver.solve(vector(load), C, C, np.zeros((6, 6)), np.zeros(6))
    solver.destroy()
    A.destroy()
    out = dolfinx.fem.Function(V)
    out.x.array[: len(y)] = y
    out.x.scatter_forward()
    return out.x.array.copy()


def _write_fields(writer, functions, t: float, field_times: set) -> None:
    if round(t, 12) in field_times:
        writer.write(functions, t)


def _bordered_counts(newton: int, linear: BorderedSolver) -> SolveStats:
    """The counters of ``newton`` iterations on a :class:`BorderedSolver`."""
    return SolveStats(
        newton_iterations=newton,
        linear_solves=linear.back_substitutions,
        factorizations=linear.factorizations,
    )


# --------------------------------------------------------------------------------------------
# Coupled
# --------------------------------------------------------------------------------------------


def run_coupled(model: TumblingBody, run: RunContext) -> None:
    """Run the coupled floating-frame solver; results go to ``run.recorder`` and ``run.fields``.

    :class:`~shoulder_fem.engine.floating.FloatingBody`, eq. (14): finite strain, frame and
    straining solved together (Simo–Tarnow energy–momentum midpoint rule: energy, linear and
    angular momentum conserved exactly). ``run.options`` may hold ``rtol``, ``atol`` (N) and
    ``max_iterations`` of the Newton solve.
    """
    recorder = run.recorder
    opts = dict(run.options or {})
    material = materials.SaintVenantKirchhoff(model.youngs_modulus, model.poisson_ratio)
    body = FloatingBody(
        model.mesh,
        model.degree,
        model.density,
        material,
        rtol=float(opts.get("rtol", 1e-10)),
        atol=opts.get("atol"),
        max_iterations=int(opts.get("max_iterations", 12)),
        name="tumbling",
    )
    props = body.props
    recorder.extra("mass_kg", props.mass)
    recorder.extra("inertia_kg_m2", props.inertia)
    strain_scale = model.density * float(model.omega0 @ model.omega0) * body.length**2
    u0 = quasi_static_straining(model, model.omega0) if model.relaxed_start else None
    body.set_initial_state(model.omega0, force_scale=strain_scale * body.length**2, u0=u0)
    reporter = Reporter(model, recorder, props.inertia, props.mass)
    inertial_u = dolfinx.fem.Function(body.V, name="displacement")
    X = body.V.tabulate_dof_coordinates().ravel()
    writer = FieldWriter(model.mesh.comm, model.mesh, run.fields / "tumbling.xdmf")
    field_times = set(np.round(model.field_times, 12))
    histories: list[list[float]] = []

    def record(t: float) -> None:
        kinetic, strain, P, L = body.measure()
        s = body.state
        reporter.record(t, s.R, s.x_g, kinetic, strain, P, L, body.max_von_mises())
        if s.history:
            histories.append(s.history)
        inertial_u.x.array[:] = body.x_n.x.array - X
        _write_fields(writer, [inertial_u, body.u, body.von_mises], t, field_times)
        run.monitor.sample()

    stats = StepperStats()
    record(model.times[0])
    try:
        march(model.times, body.advance, body.save, body.restore, on_step=record, stats=stats)
    finally:
        writer.close()
        reporter.finish()
        recorder.add_solver_counts(_bordered_counts(body.newton_iterations, body.linear), stats)
        if histories:
            recorder.extra("newton_history_first_step", histories[0])
            recorder.extra("newton_history_last_step", histories[-1])
            slowest = max(histories, key=len)
            recorder.extra("newton_history_slowest_step", slowest)
            recorder.extra("newton_iterations_max", len(slowest) - 1)
        body.destroy()


# --------------------------------------------------------------------------------------------
# Decoupled
# --------------------------------------------------------------------------------------------


class DecoupledStraining:
    """Step 3 of the decoupled method: eq. (13), linear, in the rigid frame of step 1.

    The rigid-frame inertia (Euler and centrifugal; a_G = 0 for a free body), the Coriolis term
    and the relative inertia, integrated by Newmark's average-acceleration rule. The free linear
    problem is made well posed by the same six mean-axes frame conditions as the coupled solver
    (∫ρ ũ = 0, ∫ρ Y × ũ = 0, Lagrange multipliers): they pin the rigid modes of ũ without adding
    stiffness; their multipliers are the parts of the Coriolis and relative-inertia loads the
    rigid step ignored. Collective.

    Args:
        model: the tumbling body.
        props: its mass properties (kg, m, kg m²).
        dx: the cell measure (quadrature degree ``qd``).
        qd: the quadrature degree of the forms.
    """

    def __init__(self, model: TumblingBody, props: MassProperties, dx: ufl.Measure, qd: int):
        mesh, V, rho = model.mesh, model.V, model.density
        fcp = {"quadrature_degree": qd}
        self.inertia = props.inertia
        self.omega, self.domega, a_g = (constant(mesh, np.zeros(3)) for _ in range(3))
        self.dt = constant(mesh, 1.0)
        X = ufl.SpatialCoordinate(mesh)
        #: Y = X − X_G as a UFL vector (m).
        self.Y = X - ufl.as_vector(props.centre.tolist())
        w = ufl.TestFunction(V)
        self.state = NewmarkState(V, "strain_displacement")
        self.u = u = self.state.u
        self.material = materials.LinearElastic(model.youngs_modulus, model.poisson_ratio)
        residual = (
            vp.internal_power_linear(self.material, u, w, dx)
            + vp.rigid_frame_inertia(rho, a_g, self.omega, self.domega, self.Y, w, dx)
            + vp.relative_inertia(rho, self.state.acceleration(self.dt), w, dx)
            + vp.coriolis_inertia(rho, self.omega, self.state.velocity(self.dt), w, dx)
        )
        self.r_form = dolfinx.fem.form(residual, form_compiler_params=fcp)
        self.a_form = dolfinx.fem.form(
            ufl.derivative(residual, u, ufl.TrialFunction(V)), form_compiler_params=fcp
        )
        self.A = fem_petsc.create_matrix(self.a_form)
        fem_petsc.assemble_matrix(self.A, self.a_form)
        self.A.assemble()
        self.linear = BorderedSolver(mesh.comm, self.A, "tumbling_decoupled")
        self.r_vec = fem_petsc.create_vector(self.r_form)
        self.n_owned = V.dofmap.index_map.size_local * 3
        self.C = [assemble_owned(dolfinx.fem.form(f)) for f in mean_axes_forms(rho, self.Y, w, dx)]

    def set_frame(self, s: RigidState, inertia_inverse: np.ndarray) -> None:
        """Take Ω (rad/s) from ``s`` and Ω̇ (rad/s²) from Euler's torque-free equation."""
        om = s.omega
        self.omega.value[:] = om
        self.domega.value[:] = inertia_inverse @ (-np.cross(om, self.inertia @ om))

    def solve(self, h: float) -> np.ndarray:
        """Advance ũ by one step ``h`` (s) in the current frame; return the six multipliers."""
        self.dt.value = h
        self.A.zeroEntries()
        fem_petsc.assemble_matrix(self.A, self.a_form)
        self.A.assemble()
        self.linear.set_operator(self.A)
        r = assemble_owned(self.r_form, self.r_vec)  # at ũ = ũ_n: linear, one solve is exact
        du, q = self.linear.solve(r, self.C, self.C, np.zeros((6, 6)), np.zeros(6))
        self.u.x.array[: self.n_owned] += du
        self.u.x.scatter_forward()
        self.state.advance(h)
        return q

    def destroy(self) -> None:
        """Free the PETSc objects."""
        self.linear.destroy()
        self.A.destroy()
        self.r_vec.destroy()


class DecoupledOutputs:
    """The inertial motion of the decoupled run and its measures, fields written on the grid.

    x = x_G + R(Y + ũ), v = v_G + R(Ω × (Y + ũ) + ũ̇) from the rigid state and the straining.
    """

    def __init__(
        self, model: TumblingBody, straining: DecoupledStraining, centre: np.ndarray, dx, fields
    ):
        mesh, V = model.mesh, model.V
        self.comm = mesh.comm
        self.straining, self.centre = straining, centre
        self.measures = MotionMeasures(V, model.density, dx)
        self.Yd = V.tabulate_dof_coordinates() - centre
        material, eps = straining.material, kinematics.linear_strain(straining.u)
        self.strain = dolfinx.fem.form(material.strain_energy_density(eps) * dx)
        sigma = material.stress(eps)
        Q0 = dolfinx.fem.FunctionSpace(mesh, ("DG", 0))
        self.von_mises = dolfinx.fem.Function(Q0, name="von_mises")
        self.vm_expr = dolfinx.fem.Expression(
            materials.von_mises(sigma), Q0.element.interpolation_points()
        )
        self.n_cells = mesh.topology.index_map(3).size_local
        self.inertial_u = dolfinx.fem.Function(V, name="displacement")
        self.writer = FieldWriter(self.comm, mesh, fields / "tumbling.xdmf")
        self.field_times = set(np.round(model.field_times, 12))
        self._x = None

    def measure(self, s: RigidState) -> tuple[float, float, np.ndarray, np.ndarray, float]:
        """(kinetic J, strain energy J, P kg m/s, L about the origin kg m²/s, max von Mises Pa)."""
        u, state = self.straining.u, self.straining.state
        arm = self.Yd + u.x.array.reshape(-1, 3)
        x = s.x_g + arm @ s.R.T
        v = s.v_g + (np.cross(s.omega, arm) + state.v_n.x.array.reshape(-1, 3)) @ s.R.T
        self.measures.x.x.array[:] = x.ravel()
        self.measures.v.x.array[:] = v.ravel()
        self.von_mises.interpolate(self.vm_expr)
        n = self.n_cells
        vm = self.comm.allreduce(float(np.max(self.von_mises.x.array[:n])) if n else 0.0, MPI.MAX)
        kinetic, P, L, extra = self.measures.evaluate(self.strain)
        self._x = x
        return kinetic, float(extra[0]), P, L, vm

    def write(self, t: float) -> None:
        """Write the inertial displacement, ũ and the von Mises stress at a field time ``t`` (s)."""
        self.inertial_u.x.array[:] = (self._x - self.Yd - self.centre).ravel()
        fields = [self.inertial_u, self.straining.u, self.von_mises]
        _write_fields(self.writer, fields, t, self.field_times)


def _decoupling_indicator(
    model: TumblingBody,
    straining: DecoupledStraining,
    props: MassProperties,
    dx: ufl.Measure,
    rigid: NewtonEuler,
    start: RigidState,
) -> DecouplingIndicator:
    """The decoupling indicator, its reference scales from the whole rigid motion.

    Step 1 runs before step 3 in the paper's algorithm; here it is integrated once more up front.
    G is free (a_G = 0): no orbit about an origin, hence x_g = 0 for the reference scale.
    """
    indicator = DecouplingIndicator(
        model.mesh, model.V, model.density, straining.Y, dx, props.mass, np.zeros(3), props.inertia
    )
    trajectory = rigid.integrate(start, model.times[1] - model.times[0], len(model.times) - 1)
    omegas = np.array([st.omega for st in trajectory])
    indicator.set_motion(
        omegas,
        np.array([rigid.inertia_inverse @ -np.cross(om, props.inertia @ om) for om in omegas]),
    )
    return indicator


def run_decoupled(model: TumblingBody, run: RunContext) -> None:
    """Run the decoupled method (steps 1–3 of the paper); results go to ``run.recorder``.

    Step 1 is eq. (10) integrated by :class:`~shoulder_fem.engine.rigid.NewtonEuler` with the
    mass and I_G of the mesh; step 3 is :class:`DecoupledStraining` in that recorded frame.
    """
    recorder = run.recorder
    qd = 2 * model.degree
    dx = ufl.Measure("dx", domain=model.mesh, metadata={"quadrature_degree": qd})
    props = mass_properties(model.mesh, model.density, dx)
    recorder.extra("mass_kg", props.mass)
    recorder.extra("inertia_kg_m2", props.inertia)
    # Step 1: eq. (10), the rigid motion; step 3: eq. (13), linear, in the rigid frame.
    rigid = NewtonEuler(props.mass, props.inertia)
    rstate = RigidState(x_g=props.centre, omega=model.omega0)
    straining = DecoupledStraining(model, props, dx, qd)
    last = {"rigid": rstate, "multipliers": np.zeros(6)}

    def advance(t0: float, t1: float) -> None:
        h = t1 - t0
        try:
            new = rigid.step(last["rigid"], h)
        except RuntimeError as err:
            raise ConvergenceError(
                f"t = {t1:.6g} s", str(err), rigid.last_iterations, "rigid"
            ) from err
        straining.set_frame(new, rigid.inertia_inverse)
        q = straining.solve(h)
        last["rigid"] = new
        last["multipliers"] = q

    outputs = DecoupledOutputs(model, straining, props.centre, dx, run.fields)
    reporter = Reporter(model, recorder, props.inertia, props.mass)
    indicator = _decoupling_indicator(model, straining, props, dx, rigid, rstate)

    def record(t: float) -> None:
        s = last["rigid"]
        omega, domega = straining.omega.value.copy(), straining.domega.value.copy()
        value = indicator.evaluate(straining.state, omega, domega)
        recorder.add_series_point("decoupling_indicator", t, value, "s", "1")
        if value > INDICATOR_WARNING and not last.get("warned"):
            last["warned"] = True
            logger.warning(
                "t = %.4g s: decoupling indicator %.3g > %.3g", t, value, INDICATOR_WARNING
            )
        reporter.record(t, s.R, s.x_g, *outputs.measure(s))
        outputs.write(t)
        run.monitor.sample()

    def save():
        return last["rigid"].copy(), straining.state.save()

    def restore(snap) -> None:
        last["rigid"] = snap[0].copy()
        straining.state.restore(snap[1])

    if model.relaxed_start:
        straining.u.x.array[:] = quasi_static_straining(model, model.omega0)
        straining.state.u_n.x.array[:] = straining.u.x.array
    stats = StepperStats()
    straining.set_frame(rstate, rigid.inertia_inverse)
    record(model.times[0])
    try:
        march(model.times, advance, save, restore, on_step=record, stats=stats)
    finally:
        outputs.writer.close()
        reporter.finish()
        indicator_series = recorder.series.get("decoupling_indicator", {}).get("y", [0.0])
        recorder.set_probe("max_decoupling_indicator", float(max(indicator_series)), "1")
        recorder.add_solver_counts(_bordered_counts(stats.steps, straining.linear), stats)
        recorder.extra("frame_multipliers_final", last["multipliers"])
        straining.destroy()


FAMILY = Family(
    name="tumbling-body",
    build=build,
    methods={"coupled": run_coupled, "decoupled": run_decoupled},
    dofs=dofs,
)
