"""The angle-controlled stepping shared by the coupled method and decoupled part 1.

The scapular origin of the subscapularis is a rigid plate that travels along
:data:`ACTUATION_DIRECTION`; the humeral rotation angle (the twist about the shaft axis of the
humerus's rigid rotation, or of the best fit of its nodes in the coupled method) is the progress
variable. Each step is one Newton solve in which the plate's travel is an unknown and
"twist = target" its equation (:class:`~shoulder_fem.engine.rigid_system.control.TravelControl`):
targets are hit to ``snes_atol / ANGLE_SCALE`` rad. A second-order predictor starts each step:
the tangent ``dx/dθ`` (one back-substitution with the last factorization) and its change since
the step before (:meth:`AngleStepper.predictor`). The increments adapt to the Newton iterations
(:data:`TARGET_ITERATIONS`); the way to an output angle is split into equal steps, so the
outputs every ``output_angle`` are exact and no sliver of a step is left before them
(:func:`run_steps`). An open unloaded joint is first closed by travel (:mod:`.engage`).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import dolfinx
import numpy as np
from petsc4py import PETSc

from shoulder_fem.engine.contact import Contact
from shoulder_fem.engine.progress import Progress
from shoulder_fem.engine.rigid_system import RigidBody, RigidSystem
from shoulder_fem.engine.rigid_system.control import MeasureGradient
from shoulder_fem.engine.solver import ConvergenceError, StepperStats
from shoulder_fem.families.base import RunContext
from shoulder_fem.families.shoulder.compliance import EnergyShare, PenaltyShare
from shoulder_fem.families.shoulder.engage import engage
from shoulder_fem.families.shoulder.geometry import swing_angle, twist_angle, unit
from shoulder_fem.families.shoulder.measures import Probe, VonMises, cap_contact_angles
from shoulder_fem.families.shoulder.model import ShoulderModel, ShoulderParameters
from shoulder_fem.families.shoulder.newton import (
    DIVERGENCE_TOLERANCE,
    FALLBACK_LINESEARCH,
    FALLBACK_MAX_IT,
    OUTPUT_ATOL,
    SNES_OPTIONS,
    RetryOrder,
    output_tolerance,
    solve_with_fallback,
)
from shoulder_fem.families.shoulder.outputs import (
    record_muscle_bone,
    record_swing,
    record_time_split,
    record_von_mises,
)
from shoulder_fem.families.shoulder.seating import seat
from shoulder_fem.families.shoulder.trial import SoftTissueCheck
from shoulder_fem.families.shoulder.volume import Keeping, MultiplierPredictor, augment
from shoulder_fem.io.fields import FieldWriter
from shoulder_fem.io.results import Recorder

__all__ = [
    "ACTUATION_DIRECTION",
    "ANGLE_SCALE",
    "OUTPUT_ATOL",
    "DIVERGENCE_TOLERANCE",
    "FALLBACK_LINESEARCH",
    "FALLBACK_MAX_IT",
    "SNES_OPTIONS",
    "STRETCH",
    "TARGET_ITERATIONS",
    "AngleOutputs",
    "AngleStepper",
    "StepLog",
    "Stepping",
    "drive_rotation",
    "output_tolerance",
    "run_steps",
]

logger = logging.getLogger(__name__)

#: Displacement direction of the subscapularis origin plate: medial, along the blade.
ACTUATION_DIRECTION = (-1.0, 0.0, 0.0)


#: Residual of the angle equation per radian of twist error (N/rad): with ``snes_atol`` =
#: 1e-3 N a converged step is within 1e-8 rad (6e-7 deg) of its target angle.
ANGLE_SCALE = 1e5

#: Newton iterations per step that the adaptive increments aim at: the next increment is the
#: last one times sqrt(TARGET_ITERATIONS / iterations), within [1/2, 2].
TARGET_ITERATIONS = 5
#: A step to an output angle may be this much longer than the increment, rather than leave a
#: short step before the output (:meth:`AngleStepper.reach`).
STRETCH = 1.25


@dataclass
class StepLog:
    """Counters of the stepping."""

    steps: int = 0
    failed_steps: int = 0
    fallbacks: int = 0
    first_retries_failed: int = 0  # retries whose first start failed (:class:`.RetryOrder`)
    newton_iterations: int = 0
    history: list = field(default_factory=list)
    engaging_steps: int = 0  # the converged solves of :func:`.engage.engage` (among steps)
    engaged_angle: float = 0.0  # where it handed over to the angle control (rad)
    volume_iterations: int = 0  # of the multiplier updates (.volume.augment), among the above


# ---- the angle-controlled stepper ------------------------------------------------------------


class AngleStepper:
    """Steps of the humeral angle, each one Newton solve with the actuator's travel unknown.

    A step whose Newton solve fails is cut back (halved) up to ``max_cutbacks`` times in a row,
    and at most 2 x ``max_cutbacks`` steps may fail on the way to one output angle (a short step
    that converges resets the first count, not the second: at a wall the run ends all the same);
    then the stepping stops at the last converged state.

    Attributes:
        theta: The target angle of the last converged step (rad).
        increment: The next step's angle increment (rad).
        log: The counters.
    """

    def __init__(
        self,
        system: RigidSystem,
        contact: Contact,
        actuator: RigidBody,
        direction: np.ndarray,
        measure: Callable[[bool], MeasureGradient],
        params: ShoulderParameters,
        label: str,
    ):
        self.system, self.contact, self.actuator = system, contact, actuator
        self.direction, self.measure, self.label = direction, measure, label
        self.final = params.final_angle
        self.increment = min(params.angle_step, params.max_angle_step)
        self.max_step = params.max_angle_step
        self.max_cut = int(params.max_cutbacks)
        #: kappa/mu of nearly incompressible soft tissue (the seating's continuation), or None.
        incompressible = params.incompressible_cartilage  # in both incompressible choices
        self.bulk_ratio = params.soft_tissue_bulk_ratio if incompressible else None
        #: How the incompressible tissue's volume is kept at a converged step (:func:`augment`).
        self.keeping = Keeping.of(params) if incompressible else Keeping(0.0)
        self.lagrange = MultiplierPredictor(params.soft_tissue_multiplier_prediction == "secant")
        self.log = StepLog()
        #: Where the next ``l2`` retry starts first (:class:`.newton.RetryOrder`).
        self.retry_order = RetryOrder()
        self.theta = 0.0
        self.tangent: PETSc.Vec | None = None
        #: The tangent of the converged state before, and the step from there (rad).
        self.previous: tuple[PETSc.Vec, float] | None = None
        #: Called with the angle (deg) of every converged step (progress), or None.
        self.on_angle: Callable[[float], None] | None = None

    def start(self) -> None:
        """Seat the joint unloaded (:func:`~.seating.seat`), then control the plate by angle."""
        seat(self.system, self.contact, f"{self.label} 0 deg", self.bulk_ratio)
        augment(self.system, f"{self.label} 0 deg", self.keeping)
        self.contact.commit()
        control = self.system.set_control(
            self.actuator.name, self.direction, self.measure, ANGLE_SCALE
        )
        self.theta = control.target  # the unloaded state's own angle
        self.lagrange.accept(self.theta, self.system.volumetric)
        self.system.set_options({"snes_divergence_tolerance": DIVERGENCE_TOLERANCE})
        self.tangent = self.system.control_tangent(refresh=True)  # the first step's predictor

    def travel(self) -> float:
        """The plate's travel along its direction (m)."""
        return self.system.control.travel(self.actuator.translation)

    def reach(self, goal: float) -> str | None:
        """Step until the target angle is ``goal`` (rad), adapting the increments.

        Returns:
            None, or why the stepping stopped (the state is the last converged one).
        """
        cuts = fails = 0
        while goal - self.theta > 1e-12:
            left = goal - self.theta
            longest = min(STRETCH * self.increment, self.max_step)
            step = left / math.ceil(left / longest - 1e-9)
            clipped = step < self.increment
            err, its = self.try_step(self.theta + step)
            if err is not None:
                cuts += 1
                fails += 1
                self.increment = 0.5 * step
                logger.info(
                    "%s: step %.3f -> %.3f deg cut back (%d/%d)",
                    self.label,
                    math.degrees(self.theta),
                    math.degrees(self.theta + step),
                    cuts,
                    self.max_cut,
                )
                logger.debug("%s: the step's solve: %s", self.label, err.reason)
                if cuts > self.max_cut or fails > 2 * self.max_cut:
                    return self._stalled(goal, err, cuts, fails)
                continue
            cuts = 0
            factor = float(np.clip(math.sqrt(TARGET_ITERATIONS / max(its, 1)), 0.5, 2.0))
            if clipped and factor > 1.0:  # a step shortened to land on an output
                self.increment = max(self.increment, step * factor)
            else:
                self.increment = step * factor
            self.increment = min(self.increment, self.max_step)
        return None

    def _stalled(self, goal: float, err: ConvergenceError, cuts: int, fails: int) -> str:
        why = (
            f"after {self.max_cut} cutbacks"
            if cuts > self.max_cut
            else f"in {fails} tries (more than 2 x max_cutbacks)"
        )
        return (
            f"{self.label}: stopped at {math.degrees(self.theta):.2f} deg of "
            f"{math.degrees(self.final):.0f} deg: the step towards "
            f"{math.degrees(goal):.1f} deg did not converge {why} ({err.reason})"
        )

    def try_step(self, target: float) -> tuple[ConvergenceError | None, int]:
        """Predict and solve the step to ``target`` (rad); accept it or restore the old state.

        Returns:
            (None, Newton iterations) if the step converged, else (the solver's error, 0).
        """
        system = self.system
        snap = system.snapshot()
        step = target - self.theta

        def predict(step=step):
            if self.tangent is not None:
                direction = self.predictor(step)
                system.predict(direction, step)
                direction.destroy()

        vol = system.volumetric
        multipliers = None if vol is None else vol.multiplier.copy()
        predict()
        self.lagrange.predict(target, vol)
        system.control.target = target
        name = f"{self.label} {math.degrees(target):.2f} deg"
        try:
            predicted = predict if self.tangent is not None else None
            its = solve_with_fallback(
                system, name, snap, predicted, self.log, order=self.retry_order
            )
            # the step's length follows its own solve, not the multipliers' (1-2 each)
            updates = augment(system, name, self.keeping)
            self.log.newton_iterations += updates
            self.log.volume_iterations += updates
        except ConvergenceError as err:
            system.restore(snap)
            if multipliers is not None:
                vol.multiplier[:] = multipliers
            self.log.failed_steps += 1
            return err, 0
        self.contact.commit()
        if self.previous is not None:
            self.previous[0].destroy()
        self.previous = None if self.tangent is None else (self.tangent, step)
        self.tangent = system.control_tangent()
        self.theta = target
        self.lagrange.accept(target, vol)
        if self.on_angle is not None:
            self.on_angle(math.degrees(target))
        measured = self.measure(False).value
        self.log.steps += 1
        self.log.newton_iterations += its
        self.log.history.append((self.travel(), measured, its))
        logger.info(
            "%s: travel %.3f mm, angle %.6f deg (target %.2f), %d Newton iterations",
            *(self.label, self.travel() * 1e3, math.degrees(measured), math.degrees(target), its),
        )
        return None, its

    def polish(self) -> int:
        """Newton from the converged state to ``|F| < OUTPUT_ATOL`` (an output); iterations.

        A polish that fails (it should not: it starts within ``snes_atol``) leaves the state
        as it was, with a warning.
        """
        system = self.system
        snap = system.snapshot()
        name = f"{self.label} {math.degrees(self.theta):.2f} deg (output)"
        try:
            with output_tolerance(system):
                its = system.solve(step=name)
        except ConvergenceError as err:
            system.restore(snap)
            logger.warning("%s: not tightened (%s)", name, err.reason)
            its = 0
        self.contact.commit()
        self.log.newton_iterations += its
        return its

    def predictor(self, step: float) -> PETSc.Vec:
        """The predictor's direction ``v`` for a step of ``step`` rad: ``x(θ + step) ≈ x + step v``.

        Second order: ``v = t + step / (2 h) (t - t₋)``, the tangent ``t`` here and ``t₋`` at
        the converged state a step ``h`` before (the change of the tangent over the last step
        estimates d²x/dθ²). Its rotation entries are spatial angular rates, comparable between
        the two states. Measured at ``medium``, decoupled 0-60 deg: the first residual of a
        3-deg step falls from about 900 N (the humerus's force rows) to 5-60 N, and part 1
        takes 64 Newton iterations instead of 113. The first step (no state before) uses ``t``.
        A new Vec.
        """
        v = self.tangent.copy()
        if self.previous is not None:
            before, h = self.previous
            c = step / (2.0 * h)
            v.scale(1.0 + c)
            v.axpy(-c, before)
        return v

    def destroy(self) -> None:
        """Free the tangents."""
        for vec in (self.tangent, None if self.previous is None else self.previous[0]):
            if vec is not None:
                vec.destroy()
        self.tangent = self.previous = None


def drive_rotation(
    system: RigidSystem,
    contact: Contact,
    actuator: RigidBody,
    direction: np.ndarray,
    measure: Callable[[bool], MeasureGradient],
    params: ShoulderParameters,
    on_output: Callable[[float], None],
    label: str,
) -> tuple[float, StepLog, str | None]:
    """Turn the humerus through every output angle up to the final one (collective).

    Args:
        system: The system to solve (its actuator body is prescribed; its travel becomes an
            unknown after the unloaded solve).
        contact: Its contact terms (committed after each accepted step).
        actuator: The prescribed plate of the subscapularis origin.
        direction: Unit direction of its travel.
        measure: The humeral twist (rad) and its gradient (:class:`MeasureGradient`).
        params: The scene's parameters (angles in rad).
        on_output: Callable(angle_rad) at 0 and every multiple of ``output_angle`` reached.
        label: For the progress messages.

    Returns:
        (the last angle reached in rad, counters, None or the reason the run stopped early).
    """
    every = params.output_angle
    stepper = AngleStepper(system, contact, actuator, direction, measure, params, label)
    progress = Progress(0.0, math.degrees(params.final_angle), f"{label} angle", "deg")
    stepper.on_angle = progress.to
    try:
        stepper.start()
        stepper.polish()
        on_output(0.0)
        n_outputs = int(math.floor(params.final_angle / every + 1e-9))
        goals = [k * every for k in range(1, n_outputs + 1)]
        if params.final_angle - (goals[-1] if goals else 0.0) > 1e-9:
            goals.append(params.final_angle)
        stop = engage(stepper, goals[0])
        if stop is not None:
            return stepper.theta, stepper.log, stop
        for goal in goals:
            stop = stepper.reach(goal)
            if stop is not None:
                return stepper.theta, stepper.log, stop
            if abs(goal / every - round(goal / every)) < 1e-9:  # not a final angle in between
                stepper.polish()
                on_output(goal)
        return stepper.theta, stepper.log, None
    finally:
        progress.close()
        stepper.destroy()


# ---- one stepping with its outputs ----------------------------------------------------------


@dataclass(frozen=True)
class Stepping:
    """What :func:`run_steps` drives and measures.

    Attributes:
        system: The system solved at each step; ``actuator`` is one of its bodies.
        contact: Its contact terms.
        actuator: The prescribed plate of the subscapularis origin.
        rotation: Callable -> the humerus's current rotation (3 x 3).
        measure: The humerus's twist about its shaft axis (rad) and its gradient at the current
            state (:class:`MeasureGradient`): the equation of the actuator's travel.
        probe: The per-output measurements on ``u``'s mesh.
        u: The displacement (m); its P1 interpolation is written to ``<label>.xdmf``.
        label: Names the progress messages, the fields file and the time-split probes.
        check: The soft tissues' volume ratios (recorded at each output) and the admissibility
            of the Newton trial states; None: not recorded.
        stage: The resource monitor's stage of the stepping.
        stress: The scapula's von Mises stress, recorded at each output; None: not recorded.
        on_output: Called with the angle (rad) at each output, after the series.
    """

    system: RigidSystem
    contact: Contact
    actuator: RigidBody
    rotation: Callable[[], np.ndarray]
    measure: Callable[[bool], MeasureGradient]
    probe: Probe
    u: dolfinx.fem.Function
    label: str
    stage: str
    check: SoftTissueCheck | None = None
    stress: VonMises | None = None
    on_output: Callable[[float], None] | None = None


class AngleOutputs:
    """The series and fields recorded at each output angle of a :class:`Stepping` (collective).

    ``data`` collects the outputs that ``shoulder.npz`` keeps (angles, glenoid pressure and
    shear, the last von Mises field).
    """

    def __init__(self, model: ShoulderModel, recorder: Recorder, job: Stepping, fields_dir):
        self.model, self.recorder, self.job = model, recorder, job
        self.comm = job.system.comm
        self.cap_centre, self.cap_axis, self.cap_half = model.info["humeral_cap"]
        self.data = {"angles_deg": [], "glenoid_pressure": [], "glenoid_shear": []}
        mesh = job.u.function_space.mesh
        # the P2 displacement: at the vertices in the XDMF file, whole in <label>_displacement.pvd
        self.writer = FieldWriter(self.comm, mesh, fields_dir / f"{job.label}.xdmf")
        # the body of every cell (its cell tag: meshes.shoulder's markers), for ParaView
        self.body = dolfinx.fem.Function(dolfinx.fem.FunctionSpace(mesh, ("DG", 0)), name="body")
        tags = job.probe.cell_tags
        self.body.x.array[tags.indices] = tags.values
        p = model.params
        self.penalty_share = PenaltyShare(job.u, job.probe.facet_tags, p.contact_penalty)
        self.energy_share = EnergyShare.of_model(job.u, tags, p)

    def angle(self) -> float:
        """The humerus's twist about its shaft axis (rad): the progress angle."""
        return twist_angle(self.job.rotation(), self.model.shaft_axis)

    def swing(self) -> float:
        """How far the shaft axis itself has turned (rad)."""
        return swing_angle(self.job.rotation(), self.model.shaft_axis)

    def cap_position(self) -> tuple[float, float]:
        """Where the glenoid presses on the humeral cartilage (deg; mean and largest)."""
        return cap_contact_angles(self.job.contact, self.cap_centre, self.cap_axis, self.comm)

    def __call__(self, target: float) -> None:
        """Record the outputs at target angle ``target`` (rad)."""
        job, data = self.job, self.data
        deg = math.degrees(self.angle())
        pressure, shear = job.contact.pressure_fields()  # slave and master surfaces, Pa
        p, t = job.probe.glenoid(pressure, shear)
        data["angles_deg"].append(round(math.degrees(target), 6))
        data["glenoid_pressure"].append(p)
        data["glenoid_shear"].append(t)
        x = math.degrees(target)
        self._joint_series(x, deg, p, t)
        self._muscle_series(x)
        if job.check is not None:  # how far the tissues are from the trial states' bounds
            lo, hi = job.check.j_range()
            self.recorder.add_series_point("soft_tissue_min_j", x, lo, "deg", "1")
            self.recorder.add_series_point("soft_tissue_max_j", x, hi, "deg", "1")
            top = job.check.i1bar_max()
            self.recorder.add_series_point("soft_tissue_max_i1bar", x, top, "deg", "1")
        if job.on_output is not None:
            job.on_output(target)
        if job.stress is not None:
            record_von_mises(self.recorder, job.stress, x, data, self.comm)
        stress = job.stress.fields() if job.stress else ()
        self.writer.write([job.u, pressure, shear, self.body, *stress], x)
        logger.info(
            "%s: output at %.0f deg (measured %.3f deg), max pressure %.3f MPa",
            job.label,
            x,
            deg,
            (float(p.max()) if len(p) else 0.0) / 1e6,
        )

    def _joint_series(self, x: float, deg: float, p: np.ndarray, t: np.ndarray) -> None:
        """The humerus's angles and the contact's pressure, place and resultants at ``x`` deg."""
        rec = self.recorder
        res = self.job.contact.resultants()["glenohumeral"]
        rec.add_series_point("humeral_angle", x, deg, "deg", "deg")
        record_swing(rec, x, self.job.rotation(), self.model.shaft_axis)
        mean, top = self.cap_position()
        rec.add_series_point("humeral_cap_contact_angle", x, mean, "deg", "deg")
        rec.add_series_point("humeral_cap_contact_angle_max", x, top, "deg", "deg")
        # how far the farthest contact point stays from the cartilage's edge (as meshed)
        margin = math.degrees(self.cap_half) - top
        rec.add_series_point("humeral_cap_edge_margin", x, margin, "deg", "deg")
        rec.add_series_point("max_pressure", x, float(p.max()) if len(p) else 0.0, "deg", "Pa")
        rec.add_series_point("max_shear", x, float(t.max()) if len(t) else 0.0, "deg", "Pa")
        rec.add_series_point("contact_force", x, float(np.linalg.norm(res["force"])), "deg", "N")
        rec.add_series_point("contact_area", x, float(res["area"]), "deg", "m^2")
        rec.add_series_point(
            "glenohumeral_penetration", x, float(res["max_penetration"]), "deg", "m"
        )
        share = self.penalty_share(self.job.probe.glenoid_points, p)
        rec.add_series_point("glenohumeral_penalty_share", x, share["share"], "deg", "1")
        for key in ("overlap", "glenoid_layer", "humeral_layer"):
            rec.add_series_point(f"glenohumeral_{key}", x, share[key], "deg", "m")
        energy = self.energy_share(res["penalty_energy"])
        rec.add_series_point("glenohumeral_penalty_energy_share", x, energy["share"], "deg", "1")
        for key in ("penalty_energy", "cartilage_energy"):
            rec.add_series_point(f"glenohumeral_{key}", x, energy[key], "deg", "J")
        record_muscle_bone(rec, self.job.contact, x)

    def _muscle_series(self, x: float) -> None:
        """The muscles' forces and the actuator's displacement at ``x`` deg."""
        forces = self.job.probe.muscle_forces()
        for m, f in forces.items():
            self.recorder.add_series_point(f"{m}_force", x, float(np.linalg.norm(f)), "deg", "N")
        for body, change in self.job.probe.volume_changes().items():
            self.recorder.add_series_point(f"{body}_volume_change", x, change, "deg", "1")
        travel = float(np.linalg.norm(self.job.actuator.translation))
        self.recorder.add_series_point("actuation", x, travel, "deg", "m")
        # the humerus's supports: Σ|tension| of the 4 vertical and of the horizontal elements
        tension = {k: abs(v["tension"]) for k, v in self.job.system.spring_forces().items()}
        for group in ("distal", "horizontal"):
            total = sum(v for k, v in tension.items() if k.startswith(f"humerus_{group}_"))
            self.recorder.add_series_point(f"humerus_{group}_support_force", x, total, "deg", "N")

    def stall_note(self, final: float) -> str:
        """Where the contact and the shaft had got to at the last state reached (``final``, rad)."""
        mean, top = self.cap_position()
        return (
            f"; at {math.degrees(final):.2f} deg the glenoid pressed on the humeral cartilage up "
            f"to {top:.1f} deg from its axis (force-weighted mean {mean:.1f} deg; the cartilage "
            f"ends at {math.degrees(self.cap_half):.1f} deg) and the shaft had swung "
            f"{math.degrees(self.swing()):.1f} deg"
        )

    def close(self) -> None:
        """Close the fields file."""
        self.writer.close()


def run_steps(model: ShoulderModel, run: RunContext, job: Stepping) -> dict:
    """Drive the rotation, recording every output angle (collective).

    ``job.rotation()``: the humerus's rotation; its twist about the shaft is the progress angle.

    Returns:
        The outputs for ``shoulder.npz`` (:func:`outputs.save_results`), with the final angle
        (deg) and the stop message (None if every angle was reached).
    """
    recorder = run.recorder
    cap_half = model.info["humeral_cap"][2]
    recorder.set_probe("humeral_cap_half_angle_deg", math.degrees(cap_half), "deg")
    direction = unit(ACTUATION_DIRECTION)
    outputs = AngleOutputs(model, recorder, job, run.fields)
    try:
        with run.monitor.stage(job.stage):
            final, log, stop = drive_rotation(
                job.system,
                job.contact,
                job.actuator,
                direction,
                job.measure,
                model.params,
                outputs,
                job.label,
            )
    finally:
        outputs.close()
    recorder.set_probe("final_angle_deg", math.degrees(final), "deg")
    recorder.set_probe("steps", log.steps, "1")
    recorder.set_probe("failed_steps", log.failed_steps, "1")
    recorder.set_probe("engaging_steps", log.engaging_steps, "1")
    recorder.set_probe("engaged_angle_deg", math.degrees(log.engaged_angle), "deg")
    recorder.set_probe("linesearch_fallbacks", log.fallbacks, "1")
    recorder.set_probe("first_retries_failed", log.first_retries_failed, "1")
    recorder.set_probe("volume_update_iterations", log.volume_iterations, "1")
    recorder.set_probe("newton_iterations", log.newton_iterations, "1")
    recorder.set_probe("krylov_iterations", job.system.stats.krylov_iterations, "1")
    recorder.set_probe("shortened_newton_steps", job.system.stats.shortened_steps, "1")
    recorder.set_probe("newton_step_halvings", job.system.stats.step_halvings, "1")
    recorder.set_probe("jacobian_pattern_rebuilds", job.system.stats.pattern_rebuilds, "1")
    recorder.add_solver_counts(job.system.stats, StepperStats(log.steps, log.failed_steps))
    record_time_split(recorder, job.label, job.system, job.contact)
    if stop is not None:
        stop += outputs.stall_note(final)  # at the last converged state
        recorder.set_status("incomplete", stop)
        logger.error("%s", stop)
    data = outputs.data
    data["final_angle_deg"] = math.degrees(final)
    data["glenoid_points"] = job.probe.glenoid_points
    data["stop"] = stop
    return data
