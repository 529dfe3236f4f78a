"""The time loop both driven-body methods share: step, record, write fields, log; probes at the end.

A method supplies its solve and its body-frame measures (:class:`MethodSteps`,
:class:`~shoulder_fem.families.driven_body.outputs.BodyOutputs`); this module owns the march
over the scene's times, the series recorded after each step and the field output, so both
methods record the same quantities at the same times.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import dolfinx
import numpy as np

from shoulder_fem.engine.newmark import NewmarkState
from shoulder_fem.engine.solver import NonlinearSolver, StepperStats, march
from shoulder_fem.families.base import RunContext
from shoulder_fem.families.driven_body.model import DrivenBody
from shoulder_fem.families.driven_body.outputs import BodyOutputs, LastStep, finish_probes
from shoulder_fem.io.fields import FieldWriter

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class MethodSteps:
    """What a method gives the shared time loop :func:`march_driven_body`.

    Attributes:
        state: the Newmark state (saved and restored around a step cut-back).
        solver: the method's solver (for its counters).
        advance: ``advance(t0, t1)`` solves one step (times in s) and stores the clamp reaction
            (body frame, N) and its moment (N·m) in ``last``.
        snapshot: ``snapshot(t)`` returns the displacement Functions to write at time ``t``.
        last: the last completed step; the loop keeps ``t`` and ``step`` in it.
        frame: ``frame(t)`` sets whatever the body-frame measures need at time ``t``.
        extra_record: ``extra_record(t)`` records method-specific series after each step.
    """

    state: NewmarkState
    solver: NonlinearSolver
    advance: Callable[[float, float], None]
    snapshot: Callable[[float], list[dolfinx.fem.Function]]
    last: LastStep
    frame: Callable[[float], None] | None = None
    extra_record: Callable[[float], None] | None = None


def log_progress(step: int, n_steps: int, t: float, omega: float, extra: str) -> None:
    """One log line per step on long runs (every step up to 20, then every 5 %)."""
    every = max(1, n_steps // 20)
    if step <= 20 and n_steps <= 20 or step % every == 0 or step == n_steps:
        logger.info("step %d/%d  t = %.4g s  Ω = %.4g rad/s  %s", step, n_steps, t, omega, extra)


def march_driven_body(
    model: DrivenBody, run: RunContext, steps: MethodSteps, outputs: BodyOutputs
) -> None:
    """Step through the scene's times, recording after each step; probes at the end.

    The probes describe the last completed step, also after a failed step.

    Args:
        model: the driven body.
        run: the run's recorder, resource monitor (sampled per step) and fields folder.
        steps: the method's state, solver and step functions.
        outputs: the body-frame measures.
    """
    recorder, last, frame = run.recorder, steps.last, steps.frame
    comm = model.mesh.comm
    writer = FieldWriter(comm, model.mesh, run.fields / "displacement.xdmf")
    stress_writer = FieldWriter(comm, model.mesh, run.fields / "stress.xdmf")
    field_times = set(np.round(model.field_times, 12))
    last.t, last.step = model.times[0], 0

    def record(t: float) -> None:
        last.t = t
        if frame is not None:
            frame(t)
        record_step(model, run, steps, outputs, t)
        if round(t, 12) in field_times:
            writer.write(steps.snapshot(t), t)
            stress_writer.write(outputs.update_fields(), t)
            recorder.add_series_point("max_von_mises", t, outputs.max_von_mises(), "s", "Pa")
        if steps.extra_record is not None:
            steps.extra_record(t)
        run.monitor.sample()
        history = steps.solver.stats.history
        log_progress(
            last.step,
            len(model.times) - 1,
            t,
            model.motion.rate(t),
            f"Newton {history[-1] if history else 0}, "
            f"factorizations {steps.solver.stats.factorizations}",
        )
        last.step += 1

    stats = StepperStats()
    record(model.times[0])
    try:
        march(
            model.times, steps.advance, steps.state.save, steps.state.restore, record, stats=stats
        )
    finally:
        writer.close()
        stress_writer.close()
        if frame is not None:
            frame(last.t)
        finish_probes(model, recorder, outputs, last)
        recorder.add_solver_counts(steps.solver.stats, stats)
        recorder.extra("krylov_iterations", steps.solver.stats.krylov_iterations)


def record_step(
    model: DrivenBody, run: RunContext, steps: MethodSteps, outputs: BodyOutputs, t: float
) -> None:
    """Series points of every step: tip deflection, root stress, spin rate, root torque."""
    recorder, last = run.recorder, steps.last
    recorder.add_series_point("tip_deflection", t, outputs.tip_deflection(), "s", "m")
    recorder.add_series_point("root_axial_stress", t, -last.reaction[0] / model.area, "s", "Pa")
    recorder.add_series_point("spin_rate", t, model.motion.rate(t), "s", "rad/s")
    recorder.add_series_point("root_torque", t, float(last.moment @ model.axis), "s", "N*m")
