"""A deformable body driven through a clamped face by a prescribed rotation about a fixed axis.

This is the model behind the ``driven-body`` scene family (``spinning-bar``): a straight bar,
its root face clamped to a hub on the spin axis (the z axis through the origin), the hub's
rotation prescribed by :class:`shoulder_fem.rigid.SpinUp`. Both methods run this model:

* coupled: finite-strain dynamics in the inertial frame, the clamp following the hub;
* decoupled: the hub's motion is the floating frame; eq. (13), linear, in that frame.

The quantities both methods report are measured by :class:`BodyOutputs` from two UFL
expressions each method supplies in the body (rotating) frame: the straining displacement ũ and
the stress tensor. That keeps the comparison like for like.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import dolfinx
import numpy as np
import ufl
from mpi4py import MPI
from petsc4py import PETSc

from shoulder_fem.engine.rigid import SpinUp
from shoulder_fem.engine.solver import StepperStats, march, time_grid
from shoulder_fem.meshes.bar import ROOT, TIP, build_bar
from shoulder_fem.scene import Scene, SceneError

logger = logging.getLogger(__name__)

#: Spin axes of the ``spin_axis`` parameter: across the bar (z: in-plane bending in x–y, the
#: spinning bar and the spin-up beam) or about the bar's own axis (x: a humerus in internal
#: rotation).
SPIN_AXES = {"transverse": (0.0, 0.0, 1.0), "axial": (1.0, 0.0, 0.0)}

#: Decoupled variants: the paper's eq. (13) as published; the rigid-frame inertia evaluated at the
#: strained position (spin softening); and that plus the geometric stiffness of the centrifugal
#: prestress (stress stiffening).
VARIANTS = ("paper", "spin-softening", "stress-stiffening")


def newmark_parameters(damping: float) -> tuple[float, float]:
    """Newmark (β, γ) for a numerical damping δ = γ − 1/2 ≥ 0, with β = (γ + 1/2)²/4.

    δ = 0 is the average-acceleration (trapezoidal) rule: second order, no numerical
    dissipation, unconditionally stable for linear problems — but not energy-stable for stiff
    nonlinear elastodynamics, where unresolved axial–bending modes can pump energy until Newton
    fails (a slender spinning beam does this). δ > 0 damps the high frequencies (the β above is
    the choice with the most high-frequency dissipation); the scheme is then first order, with a
    damping ratio ≈ δ ω Δt / 2 on a mode of frequency ω.
    """
    if not damping >= 0.0:
        raise ValueError(f"numerical_damping = {damping}: must be >= 0")
    gamma = 0.5 + damping
    return (gamma + 0.5) ** 2 / 4.0, gamma


@dataclass
class DrivenBody:
    """Everything both methods need to run a driven-body scene (SI units)."""

    scene: Scene
    level: str
    mesh: dolfinx.mesh.Mesh
    facet_tags: dolfinx.mesh.MeshTags
    degree: int
    n_axial: int
    density: float
    youngs_modulus: float
    poisson_ratio: float
    inner_radius: float
    outer_radius: float
    side: float
    motion: SpinUp
    times: np.ndarray
    field_times: np.ndarray
    quasi_static: bool
    variant: str = "paper"
    numerical_damping: float = 0.0

    @property
    def spin_axis(self) -> str:
        """Spin axis name: transverse (z, across the bar) or axial (x, the bar's own axis)."""
        return "axial" if abs(self.axis[0]) > 0.5 else "transverse"

    @property
    def axis(self) -> np.ndarray:
        """Unit spin axis (body = inertial components at t = 0), through the origin."""
        return self.motion.axis

    @property
    def area(self) -> float:
        """Section area, m²."""
        return self.side**2

    def analytic_axial_stress(self, r: np.ndarray, omega: float) -> np.ndarray:
        """Steady axial stress σ(r) = ρΩ²(r_out² − r²)/2 (Pa) of a bar spinning at Ω."""
        return 0.5 * self.density * omega**2 * (self.outer_radius**2 - np.asarray(r) ** 2)


def build(scene: Scene, level: str | None, comm: MPI.Comm, method: str | None = None) -> DrivenBody:
    """Check the scene's parameters together and build the mesh of ``level``."""
    p = scene.values()
    lv = scene.level(level)
    if p["outer_radius"] <= p["inner_radius"]:
        raise SceneError(
            f"{scene.where('outer_radius', 'inner_radius')}: "
            f"outer_radius = {p['outer_radius']} m must exceed "
            f"inner_radius = {p['inner_radius']} m"
        )
    if p["time_step"] > p["end_time"]:
        raise SceneError(
            f"{scene.where('time_step', 'end_time')}: "
            f"time_step = {p['time_step']} s exceeds end_time = {p['end_time']} s"
        )
    for key in ("degree", "n_axial", "n_side"):
        if key not in lv or int(lv[key]) < 1:
            raise SceneError(f"{scene.source}: levels.{level}.{key} must be a positive integer")
    times, field_times = time_grid(p["end_time"], p["time_step"], int(p["field_outputs"]))
    mesh, tags = build_bar(
        comm,
        p["inner_radius"],
        p["outer_radius"],
        p["side"],
        int(lv["n_axial"]),
        int(lv["n_side"]),
    )
    return DrivenBody(
        scene=scene,
        level=level or scene.default_level,
        mesh=mesh,
        facet_tags=tags,
        degree=int(lv["degree"]),
        n_axial=int(lv["n_axial"]),
        density=p["density"],
        youngs_modulus=p["youngs_modulus"],
        poisson_ratio=p["poisson_ratio"],
        inner_radius=p["inner_radius"],
        outer_radius=p["outer_radius"],
        side=p["side"],
        motion=SpinUp(
            p["spin_rate"], p["spin_up_time"], axis=SPIN_AXES[p.get("spin_axis", "transverse")]
        ),
        times=times,
        field_times=field_times,
        quasi_static=bool(p["quasi_static"]),
        variant=p.get("decoupled_variant", "paper"),
        numerical_damping=p.get("numerical_damping", 0.0),
    )


def vector_space(model: DrivenBody) -> dolfinx.fem.FunctionSpace:
    """The displacement space: continuous Lagrange (Q_k on hexahedra) of the level's degree."""
    return dolfinx.fem.VectorFunctionSpace(model.mesh, ("Lagrange", model.degree))


def dofs(model: DrivenBody) -> int:
    """Displacement DOFs (global)."""
    V = vector_space(model)
    return V.dofmap.index_map.size_global * V.dofmap.index_map_bs


def clamp_dofs(model: DrivenBody, V: dolfinx.fem.FunctionSpace) -> np.ndarray:
    """Blocked DOFs of the root face (clamped to the hub)."""
    fdim = model.mesh.topology.dim - 1
    return dolfinx.fem.locate_dofs_topological(V, fdim, model.facet_tags.find(ROOT.id))


def quadrature(model: DrivenBody) -> dict:
    """Form-compiler parameters: a fixed quadrature degree (exact for the linear terms)."""
    return {"quadrature_degree": 2 * model.degree}


class BodyOutputs:
    """Measures a run in the body frame; every call is collective.

    Args:
        model: the model.
        u_body: UFL expression of the straining displacement ũ (body frame, m).
        stress_body: UFL expression of the stress tensor in body-frame components (Pa).
    """

    def __init__(self, model: DrivenBody, u_body, stress_body):
        self.model = model
        mesh = model.mesh
        self.comm = mesh.comm
        params = quadrature(model)
        ds = ufl.Measure("ds", domain=mesh, subdomain_data=model.facet_tags)
        ey = ufl.as_vector((0.0, 1.0, 0.0))
        self._tip = dolfinx.fem.form(ufl.dot(u_body, ey) * ds(TIP.id), form_compiler_params=params)
        # Section-averaged σ_xx at each element layer's mid-plane: Gauss points on the
        # reference mid-plane ξ0 = 1/2 of every cell (the structured bar mesh gives every cell
        # of a layer the same section, so cells weigh alike).
        g, gw = np.polynomial.legendre.leggauss(model.degree + 1)
        g, gw = (g + 1) / 2, gw / 2
        self._points = np.array([[0.5, a, b] for a in g for b in g])
        self._weights = np.array([wa * wb for wa in gw for wb in gw])
        self._sxx_section = dolfinx.fem.Expression(stress_body[0, 0], self._points)
        n_owned = mesh.topology.index_map(3).size_local
        self._cells = np.arange(n_owned, dtype=np.int32)
        mid = dolfinx.mesh.compute_midpoints(mesh, 3, self._cells)
        edges = np.linspace(model.inner_radius, model.outer_radius, model.n_axial + 1)
        self.layer_edges = edges
        self._layer = np.clip(np.searchsorted(edges, mid[:, 0]) - 1, 0, model.n_axial - 1)
        self._layer_cells = self.comm.allreduce(
            np.bincount(self._layer, minlength=model.n_axial), op=MPI.SUM
        )
        Q0 = dolfinx.fem.FunctionSpace(mesh, ("DG", 0))
        # Fields for ParaView: axial and von Mises stress per cell (DG0, midpoint values).
        self.axial_stress = dolfinx.fem.Function(Q0, name="axial_stress")
        self.von_mises = dolfinx.fem.Function(Q0, name="von_mises")
        s = stress_body
        dev = s - ufl.tr(s) / 3 * ufl.Identity(3)
        points = Q0.element.interpolation_points()
        self._sxx_expr = dolfinx.fem.Expression(s[0, 0], points)
        self._vm_expr = dolfinx.fem.Expression(ufl.sqrt(1.5 * ufl.inner(dev, dev)), points)

    def tip_deflection(self) -> float:
        """In-plane transverse (y) tip displacement in the rotating frame, tip-face mean (m)."""
        value = dolfinx.fem.assemble_scalar(self._tip)
        return self.comm.allreduce(value, op=MPI.SUM) / self.model.area

    def axial_stress_profile(self) -> tuple[np.ndarray, np.ndarray]:
        """Section-averaged axial stress at each layer's mid-plane: (radius m, σ_xx Pa)."""
        values = self._sxx_section.eval(self._cells).reshape(len(self._cells), -1)
        cell_means = values @ self._weights
        sums = self.comm.allreduce(
            np.bincount(self._layer, weights=cell_means, minlength=self.model.n_axial),
            op=MPI.SUM,
        )
        centres = 0.5 * (self.layer_edges[:-1] + self.layer_edges[1:])
        return centres, sums / self._layer_cells

    def max_von_mises(self) -> float:
        """Largest cell value of the von Mises stress from the last :meth:`update_fields` (Pa)."""
        n_owned = self.model.mesh.topology.index_map(3).size_local
        local = float(np.max(self.von_mises.x.array[:n_owned])) if n_owned else 0.0
        return self.comm.allreduce(local, op=MPI.MAX)

    def update_fields(self) -> list[dolfinx.fem.Function]:
        """Evaluate the stress fields (collective); returns them for writing."""
        self.axial_stress.interpolate(self._sxx_expr)
        self.von_mises.interpolate(self._vm_expr)
        return [self.axial_stress, self.von_mises]


def boundary_reaction(
    residual: dolfinx.fem.FormMetaClass,
    dofs: np.ndarray,
    comm,
    coords: np.ndarray,
    rotation: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Force (N) and moment about the origin (N·m) the supports exert on ``dofs``, body frame.

    With R = P_int + P_acc − P_ext assembled without boundary conditions, the components at the
    clamped DOFs are the forces the clamp must apply to the body (variationally consistent
    reactions). ``coords`` are the DOFs' reference (body-frame) positions; the clamped nodes sit
    there in the body frame. ``rotation`` (body → inertial) turns inertial-frame residuals into
    body-frame forces.
    """
    vec = dolfinx.fem.petsc.assemble_vector(residual)
    vec.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    bs = 3
    n_owned = vec.getLocalSize() // bs
    owned = dofs[dofs < n_owned]
    forces = vec.array.reshape(-1, bs)[owned]
    vec.destroy()
    if rotation is not None:
        forces = forces @ rotation  # rows fᵀR = (Rᵀf)ᵀ
    local = np.concatenate([forces.sum(axis=0), np.cross(coords[owned], forces).sum(axis=0)])
    total = comm.allreduce(local, op=MPI.SUM)
    return total[:3], total[3:]


def dof_coordinates(V: dolfinx.fem.FunctionSpace) -> np.ndarray:
    """Reference coordinates of every (local + ghost) block DOF, shape (n, 3)."""
    return V.tabulate_dof_coordinates()


def log_progress(step: int, n_steps: int, t: float, omega: float, extra: str) -> None:
    """One log line per step on long runs (every step up to 20, then every 5 %)."""
    every = max(1, n_steps // 20)
    if step <= 20 and n_steps <= 20 or step % every == 0 or step == n_steps:
        logger.info("step %d/%d  t = %.4g s  Ω = %.4g rad/s  %s", step, n_steps, t, omega, extra)


class NewmarkState:
    """The unknown displacement and the last step's state of the Newmark rule.

    ``u`` is the unknown of the step; ``u_n, v_n, a_n`` the displacement, velocity and
    acceleration at the start of the step. :meth:`acceleration` and :meth:`velocity` are the
    rule's end-of-step values as UFL expressions of ``u`` (for the residual); :meth:`advance`
    applies the same rule to the arrays once the step has converged.
    """

    def __init__(self, V: dolfinx.fem.FunctionSpace, name: str, damping: float = 0.0):
        self.beta, self.gamma = newmark_parameters(damping)
        self.u = dolfinx.fem.Function(V, name=name)
        self.u_n, self.v_n, self.a_n = (dolfinx.fem.Function(V) for _ in range(3))

    def acceleration(self, dt):
        """a_{n+1} = (u − u_n − Δt v_n)/(βΔt²) − (1/(2β) − 1) a_n (UFL, ``dt`` a Constant)."""
        beta = self.beta
        return (self.u - self.u_n - dt * self.v_n) / (beta * dt**2) - (
            1.0 / (2 * beta) - 1.0
        ) * self.a_n

    def velocity(self, dt):
        """v_{n+1} = v_n + Δt((1 − γ) a_n + γ a_{n+1}) (UFL)."""
        gamma = self.gamma
        return self.v_n + dt * ((1 - gamma) * self.a_n + gamma * self.acceleration(dt))

    def advance(self, h: float, dynamic: bool = True) -> None:
        """Make the converged ``u`` the start of the next step (Δt = ``h`` s)."""
        beta, gamma = self.beta, self.gamma
        u, u_n, v_n, a_n = (f.x.array for f in (self.u, self.u_n, self.v_n, self.a_n))
        if dynamic:
            a_next = (u - u_n - h * v_n) / (beta * h**2) - (1.0 / (2 * beta) - 1.0) * a_n
            v_n[:] += h * ((1 - gamma) * a_n + gamma * a_next)
            a_n[:] = a_next
        u_n[:] = u

    def save(self) -> list[np.ndarray]:
        """A snapshot of the four arrays (for a step cut-back)."""
        return [f.x.array.copy() for f in (self.u, self.u_n, self.v_n, self.a_n)]

    def restore(self, snapshot: list[np.ndarray]) -> None:
        """Put a :meth:`save` snapshot back."""
        for f, arr in zip((self.u, self.u_n, self.v_n, self.a_n), snapshot, strict=True):
            f.x.array[:] = arr


def march_driven_body(
    model: DrivenBody,
    recorder,
    monitor,
    fields_dir,
    state: NewmarkState,
    solver,
    advance,
    outputs: BodyOutputs,
    snapshot,
    last: dict,
    frame=None,
    extra_record=None,
) -> None:
    """The time loop both methods share: step, record, write fields, log; probes at the end.

    Args:
        model: the driven body.
        recorder: the run's :class:`~shoulder_fem.results.Recorder`.
        monitor: the run's :class:`~shoulder_fem.resources.ResourceMonitor` (sampled per step).
        fields_dir: folder of the XDMF files.
        state: the Newmark state (saved and restored around a step cut-back).
        solver: the method's solver (for its counters).
        outputs: the body-frame measures.
        advance: ``advance(t0, t1)`` solves one step and stores the clamp reaction (body frame,
            N) in ``last["reaction"]``.
        snapshot: ``snapshot(t)`` returns the displacement Functions to write at time ``t``.
        last: shared state; this function keeps ``t`` and ``step`` in it.
        frame: ``frame(t)`` sets whatever the body-frame measures need at time ``t``.
        extra_record: ``extra_record(t)`` records method-specific series after each step.
    """
    from shoulder_fem.io.results import FieldWriter

    comm = model.mesh.comm
    writer = FieldWriter(comm, model.mesh, fields_dir / "displacement.xdmf")
    stress_writer = FieldWriter(comm, model.mesh, fields_dir / "stress.xdmf")
    field_times = set(np.round(model.field_times, 12))
    last.update(t=model.times[0], step=0)
    last.setdefault("reaction", np.zeros(3))
    last.setdefault("moment", np.zeros(3))

    def record(t: float) -> None:
        last["t"] = t
        if frame is not None:
            frame(t)
        recorder.add_series_point("tip_deflection", t, outputs.tip_deflection(), "s", "m")
        recorder.add_series_point(
            "root_axial_stress", t, -last["reaction"][0] / model.area, "s", "Pa"
        )
        recorder.add_series_point("spin_rate", t, model.motion.rate(t), "s", "rad/s")
        recorder.add_series_point("root_torque", t, float(last["moment"] @ model.axis), "s", "N*m")
        if round(t, 12) in field_times:
            writer.write(snapshot(t), t)
            stress_writer.write(outputs.update_fields(), t)
            recorder.add_series_point("max_von_mises", t, outputs.max_von_mises(), "s", "Pa")
        if extra_record is not None:
            extra_record(t)
        monitor.sample()
        history = solver.stats.history
        log_progress(
            last["step"],
            len(model.times) - 1,
            t,
            model.motion.rate(t),
            f"Newton {history[-1] if history else 0}, factorizations {solver.stats.factorizations}",
        )
        last["step"] += 1

    stats = StepperStats()
    record(model.times[0])
    try:
        march(model.times, advance, state.save, state.restore, on_step=record, stats=stats)
    finally:
        writer.close()
        stress_writer.close()
        if frame is not None:
            frame(last["t"])
        finish_probes(model, recorder, outputs, last)
        recorder.add_solver_counts(solver.stats, stats)
        recorder.extra("krylov_iterations", solver.stats.krylov_iterations)


def finish_probes(model: DrivenBody, recorder, outputs: BodyOutputs, last: dict) -> None:
    """Probes of the last completed step (also after a failed step: the completed steps stand).

    ``root_axial_stress`` is the clamp's consistent axial reaction divided by the section area
    (Pa); ``axial_stress_profile`` the section-averaged σ_xx at each layer's mid-plane.
    """
    centres, profile = outputs.axial_stress_profile()
    recorder.set_series("axial_stress_profile", centres, profile, "m", "Pa")
    if model.spin_axis == "transverse":
        recorder.set_series(
            "axial_stress_profile_analytic",
            centres,
            model.analytic_axial_stress(centres, model.motion.rate(last["t"])),
            "m",
            "Pa",
        )
    recorder.set_probe("root_axial_stress", -last["reaction"][0] / model.area, "Pa")
    # The moment the hub applies to the body (about the origin, body frame) and its component
    # along the spin axis: the driving torque.
    recorder.set_probe("root_moment", last["moment"], "N*m")
    recorder.set_probe("root_torque", float(last["moment"] @ model.axis), "N*m")
    vm = recorder.series.get("max_von_mises", {}).get("y", [])
    recorder.set_probe("max_von_mises", float(max(vm)) if vm else 0.0, "Pa")
    recorder.set_probe("tip_deflection_final", outputs.tip_deflection(), "m")
    recorder.set_probe("final_time", last["t"], "s")
    series = np.asarray(recorder.series["tip_deflection"]["y"])
    peak = int(np.argmax(np.abs(series)))
    recorder.set_probe("peak_tip_deflection", float(series[peak]), "m")
    recorder.set_probe("peak_time", float(recorder.series["tip_deflection"]["x"][peak]), "s")
    torque = np.asarray(recorder.series["root_torque"]["y"])
    recorder.set_probe("peak_root_torque", float(torque[np.argmax(np.abs(torque))]), "N*m")
    if model.spin_axis == "transverse":
        recorder.set_probe(
            "root_axial_stress_analytic",
            float(model.analytic_axial_stress(model.inner_radius, model.motion.rate(last["t"]))),
            "Pa",
        )
    else:
        # Spin about the bar's own axis: the hub's torque drives the bar's polar inertia,
        # ρ L a⁴/6 for a square section; its quasi-static peak at the largest Ω̇.
        peak_rate_dot = float(np.max(np.abs(model.motion.acceleration(model.times))))
        length = model.outer_radius - model.inner_radius
        recorder.set_probe(
            "peak_root_torque_analytic",
            model.density * length * model.side**4 / 6 * peak_rate_dot,
            "N*m",
        )
