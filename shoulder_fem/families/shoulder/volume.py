"""The volume of incompressible soft tissue kept by an augmented Lagrangian (Uzawa updates).

With ``soft_tissue_formulation = incompressible`` the tissue's pressure is p = λ + U'(θ)
(:class:`~shoulder_fem.engine.mean_dilatation.MeanDilatation`): a penalty κ on the volume ratio
θ plus multipliers λ. After each converged step :func:`augment` sets λ ← p and solves again
until the volume is kept to ``soft_tissue_volume_tolerance``; then p = λ is the incompressible
pressure whatever κ, and κ only sets how fast the updates converge.
"""

from __future__ import annotations

import logging

from shoulder_fem.engine.rigid_system import RigidSystem
from shoulder_fem.engine.solver import ConvergenceError

__all__ = ["AUGMENTATIONS", "augment"]

logger = logging.getLogger(__name__)

#: The most multiplier updates after one step.
AUGMENTATIONS = 20


def augment(system: RigidSystem, step: str, tolerance: float) -> int:
    """Update the soft tissue's pressure multipliers until the volume is kept (collective).

    Augmented Lagrangian (Uzawa): after a converged solve, λ ← p at every pressure DOF and the
    state is solved again, until the largest |ln θ| is at most ``tolerance`` (measured at
    coarse with kappa/mu = 50: 2e-3, 3e-4, 5e-5, each update a solve of 1-2 Newton iterations).
    Nothing without condensed volumetric terms or with ``tolerance`` 0. Returns the Newton
    iterations of the solves.

    Raises:
        ConvergenceError: A solve failed, or :data:`AUGMENTATIONS` updates did not reach the
            tolerance (the caller restores the state and the multipliers).
    """
    vol = system.volumetric
    if vol is None or tolerance <= 0:
        return 0
    its = 0
    for k in range(AUGMENTATIONS):
        violation = vol.violation()
        if violation <= tolerance:
            return its
        logger.debug("%s: max |ln theta| = %.3g, multipliers updated (%d)", step, violation, k)
        vol.augment()
        its += system.solve(step=f"{step} (multipliers {k + 1})")
    reason = f"the volume not kept to {tolerance:g} after {AUGMENTATIONS} multiplier updates"
    raise ConvergenceError(step, reason, its, system.prefix)
