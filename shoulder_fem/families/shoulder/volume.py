"""The volume of incompressible soft tissue kept by an augmented Lagrangian (Uzawa updates).

With ``soft_tissue_formulation = incompressible`` the tissue's pressure is p = λ + U'(θ)
(:class:`~shoulder_fem.engine.mean_dilatation.MeanDilatation`): a penalty κ on the volume ratio
θ plus multipliers λ. After each converged step :func:`augment` sets λ ← p and solves again
until the volume is kept to ``soft_tissue_volume_tolerance``; then p = λ is the incompressible
pressure whatever κ, and κ only sets how fast the updates converge.

Each update divides the volume error by a ratio that grows where the tissue is squeezed hard:
measured at coarse, with the humerus's swing held, from 0.26 at 3 deg to 0.84 at 60 deg at one
subscapularis pressure node (multiplier 13 MPa, J 0.057), so that 20 updates no longer kept the
volume to 1e-4. The method of multipliers' remedy (Bertsekas 1982, sec. 2.2: raise the penalty
when an update gains too little) is :class:`Keeping`'s ``most_raise``: κ is raised 4× whenever
an update leaves more than half of the error, up to ``most_raise`` × κ, for the rest of the
step only; once the volume is kept, λ takes the pressure, κ is given back and the state is
solved once more, so the step ends in equilibrium at the scene's κ as without the raise.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from shoulder_fem.engine.solver import ConvergenceError

__all__ = ["AUGMENTATIONS", "RAISE", "SLOW_UPDATE", "Keeping", "MultiplierPredictor", "augment"]

logger = logging.getLogger(__name__)

#: The most multiplier updates after one step (a solve at the given-back κ counts as one).
AUGMENTATIONS = 20
#: An update that leaves more than this fraction of the volume error raises κ (Bertsekas's γ;
#: his 0.25 raised κ at many of the default run's steps at coarse and cost 34 % more Newton
#: iterations, 744 against 555; 0.5: 552) ...
SLOW_UPDATE = 0.5
#: ... by this factor (Bertsekas's β: 4-10).
RAISE = 4.0


@dataclass(frozen=True)
class Keeping:
    """How the volume is kept.

    ``tolerance``: on max |ln θ| (0: not at all, a plain penalty); ``most_raise``: the most κ
    is raised within a step (1: never, plain Uzawa updates).
    """

    tolerance: float
    most_raise: float = 1.0

    def __post_init__(self):
        if not self.tolerance >= 0 or not self.most_raise >= 1:
            raise ValueError(f"Keeping: tolerance >= 0 and most_raise >= 1, got {self}")

    @classmethod
    def of(cls, params) -> Keeping:
        """The scene's (``soft_tissue_volume_tolerance``, ``soft_tissue_penalty_raise``)."""
        return cls(params.soft_tissue_volume_tolerance, params.soft_tissue_penalty_raise)


def augment(system, step: str, keeping: Keeping) -> int:
    """Update the soft tissue's pressure multipliers until the volume is kept (collective).

    ``system``: anything with ``volumetric`` (a MeanDilatation or None), ``solve(step=...)``
    (Newton iterations) and ``prefix`` -- a RigidSystem or a NonlinearSolver.

    Augmented Lagrangian (Uzawa): after a converged solve, λ ← p at every pressure DOF and the
    state is solved again, until the largest |ln θ| is at most ``keeping.tolerance`` (measured
    at coarse with kappa/mu = 50: 2e-3, 3e-4, 5e-5, each update a solve of 1-2 Newton
    iterations). κ is raised within the step as the module says. Nothing without condensed
    volumetric terms or with the tolerance 0. Returns the Newton iterations of the solves.

    Raises:
        ConvergenceError: A solve failed, or :data:`AUGMENTATIONS` updates did not reach the
            tolerance (the caller restores the state and the multipliers; κ is given back).
    """
    vol = system.volumetric
    if vol is None or keeping.tolerance <= 0:
        return 0
    base = vol.bulk_factor
    its, last = 0, None
    try:
        for k in range(AUGMENTATIONS):
            violation = vol.violation()
            if violation <= keeping.tolerance:
                if vol.bulk_factor == base:
                    return its
                vol.augment()  # λ ← p at the raised κ, then the scene's κ and a solve again
                vol.scale_bulk(base)
                logger.debug("%s: volume kept at the raised kappa, given back (%d)", step, k)
                its += system.solve(step=f"{step} (multipliers {k + 1}, kappa given back)")
                last = None
                continue
            raised = vol.bulk_factor * RAISE
            if last is not None and violation > SLOW_UPDATE * last:
                if raised <= keeping.most_raise * base * (1 + 1e-12):
                    vol.scale_bulk(raised)
            logger.debug(
                "%s: max |ln theta| = %.3g, multipliers updated (%d, kappa x%g)",
                step, violation, k, vol.bulk_factor / base,
            )  # fmt: skip
            last = violation
            vol.augment()
            its += system.solve(step=f"{step} (multipliers {k + 1})")
    finally:
        if vol.bulk_factor != base:
            vol.scale_bulk(base)
    reason = (
        f"the volume not kept to {keeping.tolerance:g} after {AUGMENTATIONS} multiplier updates"
    )
    raise ConvergenceError(step, reason, its, system.prefix)


class MultiplierPredictor:
    """The multipliers at a step's start, extrapolated from the last two converged steps.

    λ follows the pressure, smooth in the angle: λ(θ) ≈ λ₁ + (λ₁ - λ₀)(θ - θ₁)/(θ₁ - θ₀)
    (a secant, as the displacement's tangent prediction), so that the step's own solve leaves a
    smaller volume error for :func:`augment`. ``enabled`` False: λ stays at the last step's.
    """

    def __init__(self, enabled: bool = True):
        self.enabled = enabled
        self._last: tuple[float, np.ndarray] | None = None
        self._before: tuple[float, np.ndarray] | None = None

    def accept(self, theta: float, vol) -> None:
        """Record the converged step's angle (rad) and multipliers (``vol`` None: nothing)."""
        if vol is not None:
            self._before, self._last = self._last, (theta, vol.multiplier.copy())

    def predict(self, theta: float, vol) -> None:
        """Set ``vol``'s multipliers for the step to ``theta`` (rad), once two steps are known."""
        if vol is None or not self.enabled or self._before is None:
            return
        (t1, l1), (t0, l0) = self._last, self._before
        if t1 == t0:
            return
        vol.multiplier[:] = l1 + (l1 - l0) * ((theta - t1) / (t1 - t0))
