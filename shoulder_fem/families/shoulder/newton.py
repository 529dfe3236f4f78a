"""The Newton settings of the shoulder's solves and their retry with a line search.

Shared by the unloaded solve (:mod:`~.seating`), the engagement (:mod:`~.engage`) and the angle
steps (:mod:`~.stepping`).
"""

from __future__ import annotations

import contextlib
import logging

from shoulder_fem.engine.rigid_system import RigidSystem
from shoulder_fem.engine.solver import ConvergenceError

__all__ = [
    "DIVERGENCE_TOLERANCE",
    "FALLBACK_LINESEARCH",
    "FALLBACK_MAX_IT",
    "OUTPUT_ATOL",
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


def solve_with_fallback(
    system: RigidSystem,
    step: str,
    snap,
    predict=None,
    log=None,
    divergence_tolerance: float = DIVERGENCE_TOLERANCE,
) -> int:
    """Solve; if Newton ran out of iterations, solve again with the ``FALLBACK_LINESEARCH``.

    The second solve starts from ``snap`` (a :meth:`RigidSystem.snapshot`), re-predicted by
    ``predict()`` if given. ``log`` (a :class:`~.stepping.StepLog`, or None) counts the retry
    and the first solve's iterations. ``divergence_tolerance``: the solver's own, set again after
    the retry (-1: none). Returns the Newton iterations of the solve that converged.

    Raises:
        ConvergenceError: Both solves failed (the reason of the second).
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
        if log is not None:
            log.fallbacks += 1
            log.newton_iterations += err.iterations
        system.restore(snap)
        if predict is not None:
            predict()
        _, _, _, max_it = system.snes.getTolerances()
        fallback = {"snes_linesearch_type": FALLBACK_LINESEARCH, "snes_divergence_tolerance": -1.0}
        system.set_options(fallback | {"snes_max_it": FALLBACK_MAX_IT})
        try:
            return system.solve(step=f"{step} ({FALLBACK_LINESEARCH} line search)")
        finally:
            system.set_options(
                {
                    "snes_linesearch_type": original,
                    "snes_divergence_tolerance": divergence_tolerance,
                    "snes_max_it": max_it,
                }
            )
