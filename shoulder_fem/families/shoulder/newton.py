"""The Newton settings of the shoulder's solves and their retry with a line search.

Shared by the unloaded solve (:mod:`~.seating`), the engagement (:mod:`~.engage`) and the angle
steps (:mod:`~.stepping`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging

from shoulder_fem.engine.petsc_lib import line_search_maxstep
from shoulder_fem.engine.rigid_system import RigidSystem
from shoulder_fem.engine.solver import ConvergenceError

__all__ = [
    "DIVERGENCE_TOLERANCE",
    "FALLBACK_LINESEARCH",
    "FALLBACK_MAX_IT",
    "OUTPUT_ATOL",
    "RetryOrder",
    "SNES_OPTIONS",
    "output_tolerance",
    "solve_with_fallback",
]

logger = logging.getLogger(__name__)

#: Newton settings of the nonlinear solves. Joint forces are ~10-100 N: atol 1e-3 N is 1e-5 of
#: them. Newton converges quadratically to the end: the contact's tangent includes the change
#: of its segments as the surfaces slide (:mod:`shoulder_fem.engine.contact.segment_tangent`;
#: without it the tail was linear, 0.44-0.56 per iteration at coarse). Full Newton steps
#: (``basic``; each shortened by the trial-state guard when it would invert a tissue element
#: or give a non-finite residual) are the fastest almost everywhere: the steps take 3-6
#: iterations. Where a full step overshoots from one contact state into another (part 1, the
#: first step at ``paper``: the residual from 198 to 4 030 N, then 15 guarded iterations without
#: converging; at coarse 30 -> 35 deg, likewise) the ``l2`` line search (a secant minimisation
#: of |F|^2 along the Newton direction) converges in 4-11. So a step's solve whose residual
#: grows beyond ``DIVERGENCE_TOLERANCE`` times its start, or that has not converged in
#: ``snes_max_it`` = 15 iterations, is retried from the step's start with ``FALLBACK_LINESEARCH``
#: (up to ``FALLBACK_MAX_IT`` iterations, no divergence test) before the step is cut back. The
#: unloaded solve has no divergence test (its residual oscillates by 10x and more on the way
#: while the contact seats, in some scenes).
#: ``l2`` everywhere is 3-5 times slower in the coupled solve (residual decrease ~0.9 per
#: iteration from the first step on; ``bt`` and ``cp`` too; ``bt`` as the fallback failed the
#: first step at ``paper`` in 60 iterations).
SNES_OPTIONS = {
    "snes_rtol": 1e-8,
    "snes_atol": 1e-3,
    "snes_max_it": 15,
    "snes_linesearch_type": "basic",
}
FALLBACK_LINESEARCH = "l2"
FALLBACK_MAX_IT = 60
#: The first of two retries' iterations: the retries that converge take 4-11 (from the step's
#: start at coarse: 10 and 7), so a first retry that has not converged in 20 gives way to the
#: second (part 1 at coarse, 8.13 deg: 60 iterations from the start in vain, then 5 from the
#: prediction).
FIRST_RETRY_MAX_IT = 20
FALLBACK_MAX_LAMBDA = 1.0
#: PETSc's default largest line-search step: given back after the retries when the library
#: cannot be asked for the one before (:func:`~shoulder_fem.engine.petsc_lib.line_search_maxstep`).
PETSC_MAXSTEP = 1e8
DIVERGENCE_TOLERANCE = 10.0

#: Newton's absolute tolerance (N) at the output angles (:meth:`.stepping.AngleStepper.polish`):
#: a step stops at ``snes_atol`` = 1e-3 N (1e-5 of the joint forces), an output goes on to
#: 1e-6 N, one iteration more at most (Newton converges quadratically there), so that the
#: transferred loads balance part 1's springs to about 1e-8 of them (issue 21) and what the
#: methods are compared on is exact to well below what separates them.
OUTPUT_ATOL = 1e-6


@contextlib.contextmanager
def output_tolerance(system: RigidSystem, tolerance: float = OUTPUT_ATOL):
    """Newton's absolute tolerance at ``tolerance`` (N) within the block (if that is tighter)."""
    atol = system.snes.getTolerances()[1]
    system.set_options({"snes_atol": min(tolerance, atol)})
    try:
        yield
    finally:
        system.set_options({"snes_atol": atol})


@dataclasses.dataclass
class RetryOrder:
    """Where an angle step's ``l2`` retry starts first: the start that converged last time.

    Measured 2026-11-29 (the default scene, 0-60 deg, both starts tried, the step's start
    first): every retry of the coupled runs converged from the step's start (2 at coarse, 2 at
    medium, 1 at paper; at coarse in 10 and 7 iterations; from the prediction the coupled
    retries at 8.13 and 42.50 deg at coarse fail in 20 iterations, so both steps were cut back
    before), while part 1's converged from the prediction after 20 iterations in vain from the
    step's start in 8 of its 10 retried steps (1 of 2 at coarse, 2 of 3 at medium, 5 of 5 at
    paper). Which start suits a run is a property of its tangent, so each stepper keeps the
    order that last worked.
    """

    prediction_first: bool = False


def solve_with_fallback(
    system: RigidSystem,
    step: str,
    snap,
    predict=None,
    log=None,
    divergence_tolerance: float = DIVERGENCE_TOLERANCE,
    order: RetryOrder | None = None,
) -> int:
    """Solve; if Newton ran out of iterations, solve again with the ``FALLBACK_LINESEARCH``.

    The retry starts from ``snap`` (a :meth:`RigidSystem.snapshot`) as it is and, if that fails
    and ``predict`` is given, from ``snap`` re-predicted by ``predict()``; with ``order`` (a
    :class:`RetryOrder`, whose docstring has the measurements) the start that converged last
    is tried first, and ``order`` is updated. The ``l2`` line search does not extrapolate past
    the full Newton step, the one the trial-state guard checked (``snes_linesearch_maxstep`` =
    1; measured, coupled at coarse: without it a retry at 27.71 deg ended in
    ``DIVERGED_FNORM_NAN`` after 9 iterations and the step was cut back).

    ``log`` (a :class:`~.stepping.StepLog`, or None) counts the retries and the failed solves'
    iterations. ``divergence_tolerance``: the solver's own, set again after the retries (-1:
    none). Returns the Newton iterations of the solve that converged.

    Raises:
        ConvergenceError: Every solve failed (the reason of the last).
    """
    try:
        return system.solve(step=step)
    except ConvergenceError as err:
        original = system.linesearch
        if original == FALLBACK_LINESEARCH or not any(
            why in err.reason for why in ("MAX_IT", "DTOL", "LOCAL_MIN")
        ):
            raise  # a failed factorization: the step is too long
        logger.info("%s: retried with the %s line search", step, FALLBACK_LINESEARCH)
        logger.debug("%s: the full-step solve: %s", step, err.reason)
        failed = err
    _, _, _, max_it = system.snes.getTolerances()
    maxstep = line_search_maxstep(system.snes) or PETSC_MAXSTEP  # None: not known
    fallback = {
        "snes_linesearch_type": FALLBACK_LINESEARCH,
        "snes_divergence_tolerance": -1.0,
        "snes_linesearch_maxstep": FALLBACK_MAX_LAMBDA,
    }
    system.set_options(fallback)
    starts = [(None, "")]
    if predict is not None:
        starts = [(None, ", from the step's start"), (predict, ", from the prediction")]
        if order is not None and order.prediction_first:
            starts.reverse()
    try:
        for k, (start, where) in enumerate(starts):
            last = k == len(starts) - 1
            system.set_options({"snes_max_it": FALLBACK_MAX_IT if last else FIRST_RETRY_MAX_IT})
            if log is not None:
                log.fallbacks += 1
                log.newton_iterations += failed.iterations
            system.restore(snap)
            if start is not None:
                start()
            try:
                its = system.solve(step=f"{step} ({FALLBACK_LINESEARCH} line search{where})")
            except ConvergenceError as err:
                failed = err
                if log is not None and not last:
                    log.first_retries_failed += 1
            else:
                if order is not None and predict is not None:
                    order.prediction_first = start is not None
                return its
        raise failed
    finally:
        system.set_options(
            {
                "snes_linesearch_type": original,
                "snes_divergence_tolerance": divergence_tolerance,
                "snes_max_it": max_it,
                "snes_linesearch_maxstep": maxstep,
            }
        )
