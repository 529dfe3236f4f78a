"""Trial states inside the admissible set: Newton steps shortened in the line search's pre-check.

A full Newton step from a state far from equilibrium can invert elements of a soft body or
distort the contact surfaces until the residual is NaN or 1e55; such a step used to end the
solve and the whole load step was cut back. :class:`TrialGuard` is the SNES line search's
pre-check (``SNESLineSearchSetPreCheck``): before the line search evaluates the residual at
``x - y`` it tests the trial state -- the model's ``admissible()`` test (e.g. no inverted
element), then a finite residual -- and halves ``y`` until the trial passes (at most
``max_halvings`` times). The residual it evaluated at the accepted trial is handed to the line
search's own evaluation at the same point (:meth:`TrialGuard.residual` is the SNES function),
so a step that needs no shortening costs nothing more. The tests bound trial states only: a
converged state is never changed by them.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

__all__ = ["TrialGuard"]


class TrialGuard:
    """The pre-check: halve the Newton step ``y`` until ``x - y`` passes (collective).

    Args:
        update_state: Sets the model's state from a reduced vector.
        residual: The SNES residual callback ``residual(snes, x, r)``.
        admissible: Callable() -> bool at the current state, the same on every rank; None:
            only the residual's finiteness is tested.
        stats: Counts the Newton steps shortened (``shortened_steps``) and the halvings
            (``step_halvings``).
        comm: The communicator.
        max_halvings: Halvings allowed per Newton step.
        correct: Callable(x, y) -> bool applied to every Newton step first (changes ``y`` in
            place; True if it did), e.g. :meth:`~.corotation.RigidRegions.precheck`; None:
            none.
    """

    def __init__(
        self,
        update_state: Callable[[PETSc.Vec], None],
        residual: Callable[[PETSc.SNES | None, PETSc.Vec, PETSc.Vec], None],
        admissible: Callable[[], bool] | None,
        stats,
        comm: MPI.Comm,
        max_halvings: int = 20,
        correct: Callable[[PETSc.Vec, PETSc.Vec], bool] | None = None,
    ):
        self.update_state, self._residual = update_state, residual
        self.correct = correct
        self.admissible, self.stats, self.comm = admissible, stats, comm
        self.max_halvings = int(max_halvings)
        self._trial: PETSc.Vec | None = None
        self._r: PETSc.Vec | None = None
        #: (x, r) of the last accepted trial, for the line search's next evaluation.
        self._pending: tuple[np.ndarray, np.ndarray] | None = None

    def residual(self, snes: PETSc.SNES | None, x: PETSc.Vec, r: PETSc.Vec) -> None:
        """SNES residual: the pre-check's, if it was evaluated at this same ``x``."""
        pending, self._pending = self._pending, None
        same = pending is not None and np.array_equal(pending[0], x.array_r)
        if self.comm.allreduce(same, op=MPI.LAND):
            r.array[:] = pending[1]
            return
        self._residual(snes, x, r)

    def __call__(self, x: PETSc.Vec, y: PETSc.Vec) -> bool:
        """SNES pre-check callback: correct, then shorten ``y`` in place; True if it changed."""
        if self._trial is None or self._trial.getSizes() != x.getSizes():
            self.destroy()
            self._trial, self._r = x.duplicate(), x.duplicate()
        corrected = bool(self.correct(x, y)) if self.correct is not None else False
        scale = 1.0
        for _ in range(self.max_halvings):
            if self._passes(x, y, scale):
                break
            scale *= 0.5
            self.stats.step_halvings += 1
        else:
            self._passes(x, y, scale)  # the last one: the line search takes it as it is
        if scale == 1.0:
            return corrected
        y.scale(scale)
        self.stats.shortened_steps += 1
        return True

    def _passes(self, x: PETSc.Vec, y: PETSc.Vec, scale: float) -> bool:
        """Whether ``x - scale y`` is admissible with a finite residual (state left there)."""
        trial = self._trial
        x.copy(trial)
        trial.axpy(-scale, y)
        self._pending = None
        self.update_state(trial)
        if self.admissible is not None and not self.admissible():
            return False
        self._residual(None, trial, self._r)
        finite = bool(np.all(np.isfinite(self._r.array_r)))
        if not self.comm.allreduce(finite, op=MPI.LAND):
            return False
        self._pending = (trial.array_r.copy(), self._r.array_r.copy())
        return True

    def destroy(self) -> None:
        """Free the work vectors."""
        for vec in (self._trial, self._r):
            if vec is not None:
                vec.destroy()
        self._trial = self._r = None
