"""The hertz scene's run: load steps with cut-back, probes and series against Hertz, fields."""

from __future__ import annotations

import logging

import dolfinx
import numpy as np

from shoulder_fem.engine.contact import record_resultants
from shoulder_fem.engine.solver import StepperStats, march
from shoulder_fem.families.base import RunContext
from shoulder_fem.families.hertz.model import SYMMETRY_FACTOR, HertzModel
from shoulder_fem.families.hertz.problem import HertzProblem
from shoulder_fem.families.hertz.theory import HertzSolution, fit_hertz_profile, hertz_profile
from shoulder_fem.io.fields import FieldWriter
from shoulder_fem.io.results import Recorder

logger = logging.getLogger(__name__)


def run_coupled(model: HertzModel, run: RunContext) -> None:
    """Press the ball to the scene's force in ``load_steps`` increments; record against Hertz.

    The increments are load factors stepped by :func:`~shoulder_fem.engine.solver.march`: a
    load step whose solve fails is cut back (halved) and the counters say so.
    """
    recorder = run.recorder
    problem = HertzProblem(model, run.options)
    _record_parameters(model, recorder)
    stepper = StepperStats()
    reached = [0.0]

    def advance(t0: float, t1: float) -> None:
        problem.reach(model.force * t1, step=f"load {t1:.6g} F")

    def on_step(t: float) -> None:
        reached[0] = model.force * t
        _record_step(model, problem, recorder, reached[0])
        run.monitor.sample()

    times = np.linspace(0.0, 1.0, model.load_steps + 1)
    try:
        march(times, advance, problem.save, problem.restore, on_step=on_step, stats=stepper)
    finally:
        _record(model, problem, recorder, reached[0], stepper)
    _write_fields(problem, run.fields)
    problem.solver.destroy()


def _record_parameters(model: HertzModel, recorder: Recorder) -> None:
    recorder.set_parameter("socket_radius", model.socket_radius, "m")
    if model.deformable:
        recorder.set_parameter("counterpart_youngs_modulus", model.counterpart_youngs_modulus, "Pa")
        recorder.set_parameter("counterpart_poisson_ratio", model.counterpart_poisson_ratio, "1")
        recorder.set_parameter("block_half_width_m", model.block_half_width, "m")
        recorder.set_parameter("block_depth_m", model.block_depth, "m")
    else:
        recorder.set_parameter("counterpart_youngs_modulus", "rigid", "Pa")
        recorder.set_parameter("counterpart_poisson_ratio", "rigid", "1")
        recorder.set_parameter("block_half_width", None, "1")
        recorder.set_parameter("block_depth", None, "1")
    recorder.set_parameter("penalty", model.penalty, "Pa/m")
    recorder.set_parameter("h_contact", model.h_contact, "m")


def _record_step(model: HertzModel, problem: HertzProblem, recorder: Recorder, force: float):
    """The series point of one load step reached (force ``force``, N)."""
    res = problem.contact.resultants()["ball"]
    theory = model.theory(force)
    radius = problem.contact_radius(res)
    recorder.add_series_point("max_contact_pressure", force, res["max_pressure"], "N", "Pa")
    recorder.add_series_point("hertz_max_pressure", force, theory.max_pressure, "N", "Pa")
    recorder.add_series_point("contact_radius", force, radius, "N", "m")
    recorder.add_series_point("hertz_contact_radius", force, theory.contact_radius, "N", "m")
    recorder.add_series_point("approach", force, problem.delta, "N", "m")
    logger.info(
        "hertz: F = %.6g N, p_max = %.6g Pa (Hertz %.6g), a = %.6g m (Hertz %.6g)",
        force,
        res["max_pressure"],
        theory.max_pressure,
        radius,
        theory.contact_radius,
    )


def _record(
    model: HertzModel,
    problem: HertzProblem,
    recorder: Recorder,
    reached: float,
    stepper: StepperStats,
) -> None:
    """The probes at the last force reached, the pressure profile and the solver counters."""
    res = problem.contact.resultants()["ball"]
    theory = model.theory(reached) if reached > 0 else None
    radius = problem.contact_radius(res)
    recorder.set_probe("force_reached", reached, "N")
    recorder.set_probe("contact_force", SYMMETRY_FACTOR * float(res["force"][2]), "N")
    recorder.set_probe("top_reaction_force", problem.top_reaction(), "N")
    bottom = problem.bottom_reaction()
    if bottom is not None:
        recorder.set_probe("bottom_reaction_force", bottom, "N")
    recorder.set_probe("max_contact_pressure", res["max_pressure"], "Pa")
    recorder.set_probe("contact_radius", radius, "m")
    recorder.set_probe("contact_area", SYMMETRY_FACTOR * res["area"], "m^2")
    recorder.set_probe("approach", problem.delta, "m")
    recorder.set_probe("max_penetration", res["max_penetration"], "m")
    record_resultants(problem.contact, recorder, prefix="quarter_")  # the modelled quarter's
    if theory is not None:
        recorder.set_probe("hertz_max_pressure", theory.max_pressure, "Pa")
        recorder.set_probe("hertz_contact_radius", theory.contact_radius, "m")
        recorder.set_probe("hertz_effective_modulus", theory.effective_modulus, "Pa")
        recorder.set_probe(
            "max_pressure_rel_error", res["max_pressure"] / theory.max_pressure - 1.0, "1"
        )
        recorder.set_probe("contact_radius_rel_error", radius / theory.contact_radius - 1.0, "1")
    r, p = problem.pressure_profile()
    recorder.set_series("pressure_profile", r, p, "m", "Pa")
    if theory is not None:
        _record_profile(model, problem, recorder, theory, r, p, reached)
    recorder.add_solver_counts(problem.solver.stats, stepper)
    recorder.extra("newton_iterations_per_solve", list(problem.newton))
    recorder.extra("uzawa_iterations_per_solve", list(problem.uzawa))
    cs = problem.contact.stats
    recorder.extra(
        "contact",
        {
            "evaluations": cs.evaluations,
            "search_s": cs.search_s,
            "assembly_s": cs.assembly_s,
            "pattern_merges": cs.pattern_merges,
        },
    )


def _record_profile(
    model: HertzModel,
    problem: HertzProblem,
    recorder: Recorder,
    theory: HertzSolution,
    r: np.ndarray,
    p: np.ndarray,
    reached: float,
) -> None:
    """The Hertz profile fitted to the nodal pressures, the pole's pressure, their scatter.

    ``r``, ``p`` are the contact points' radii and pressures on rank 0 (empty elsewhere); the
    fit is made there and its numbers sent to every rank.
    """
    comm = problem.u.function_space.mesh.comm
    fit = pole = None
    if comm.rank == 0 and len(r) >= 2:
        fit = fit_hertz_profile(r, p)
        pole = float(p[0]) if r[0] <= 1e-9 * theory.contact_radius else None
    fit, pole = comm.bcast((fit, pole), root=0)
    if fit is not None:
        p0 = theory.max_pressure
        recorder.set_probe("fitted_max_pressure", fit.max_pressure, "Pa")
        recorder.set_probe("fitted_max_pressure_rel_error", fit.max_pressure / p0 - 1.0, "1")
        recorder.set_probe("fitted_contact_radius", fit.contact_radius, "m")
        recorder.set_probe(
            "fitted_contact_radius_rel_error", fit.contact_radius / theory.contact_radius - 1.0, "1"
        )
        recorder.set_probe("pressure_scatter", fit.rms, "Pa")
        recorder.set_probe("pressure_scatter_rel", fit.rms / fit.max_pressure, "1")
        recorder.set_probe("fitted_points", fit.points, "1")
    if pole is not None:
        recorder.set_probe("pole_pressure", pole, "Pa")
        recorder.set_probe("pole_pressure_rel_error", pole / theory.max_pressure - 1.0, "1")
    rr = np.linspace(0.0, theory.contact_radius, 50)
    pp = hertz_profile(rr, theory.max_pressure, theory.contact_radius)
    recorder.set_series("hertz_pressure_profile", rr, pp, "m", "Pa")
    if comm.rank == 0 and len(r):
        from shoulder_fem.io.plots import plot_pressure_profile

        fitted = None
        if fit is not None:
            rf = np.linspace(0.0, fit.contact_radius, 50)
            fitted = (rf, hertz_profile(rf, fit.max_pressure, fit.contact_radius))
        plot_pressure_profile(
            r,
            p,
            (rr, pp),
            recorder.folder / "pressure_profile.png",
            title=f"hertz ({model.geometry}, {model.level}): F = {reached:.4g} N",
            fitted=fitted,
        )


def _write_fields(problem: HertzProblem, fields_dir) -> None:
    mesh = problem.V.mesh
    V1 = dolfinx.fem.VectorFunctionSpace(mesh, ("Lagrange", 1))
    u1 = dolfinx.fem.Function(V1, name="displacement")
    u1.interpolate(problem.u)
    pressure, shear = problem.contact.pressure_fields()
    with FieldWriter(mesh.comm, mesh, fields_dir / "contact.xdmf") as writer:
        writer.write([u1, pressure, shear], 1.0)
