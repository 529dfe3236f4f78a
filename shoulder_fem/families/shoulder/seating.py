"""The unloaded solve of the shoulder (the joint seating), by continuation in the contact penalty.

At rest the faceted cartilage layers overlap a little, so the first Newton residual is the
penalty times that overlap: about 240 N at ``coarse`` with the default 5 MPa/mm, which Newton
resolves in 9 iterations. Ten times stiffer, the first residual is 2 400 N and Newton cycles
between active sets without converging (measured at 50 MPa/mm: no convergence in 60
iterations). The same equilibrium is reached by a continuation: each pair's penalty scaled
down to :data:`SEATING_PENALTY` for the stiffest (the glenohumeral pair's), then raised by
:data:`PENALTY_RATIO` per solve up to its own, each solve starting from the one before. Only
the path changes: the final solve is the scene's own (tested: the seated state equals a
direct solve's where that converges).
"""

from __future__ import annotations

import logging

from shoulder_fem.engine.contact import Contact
from shoulder_fem.engine.rigid_system import RigidSystem

__all__ = ["PENALTY_RATIO", "SEATING_PENALTY", "seat", "seating_factors"]

logger = logging.getLogger(__name__)

#: The largest penalty (Pa/m) the seating is solved with directly: the default's (5 MPa/mm),
#: which seats in 9 Newton iterations at ``coarse``.
SEATING_PENALTY = 5e9
#: The penalty's growth from one continuation solve to the next (measured at ``coarse``,
#: 50 MPa/mm: 8, 4 and 3 iterations at 0.1, 0.3 and 0.9 of it, then the full penalty).
PENALTY_RATIO = 3.0


def seating_factors(penalty: float) -> list[float]:
    """The penalty scale factors of the seating solves for a largest penalty ``penalty`` (Pa/m).

    ``[1.0]`` (one direct solve) up to :data:`SEATING_PENALTY`; above it, the factors from
    ``SEATING_PENALTY / penalty`` up by :data:`PENALTY_RATIO`, then 1.
    """
    factors, f = [], SEATING_PENALTY / penalty
    while f < 1.0:
        factors.append(f)
        f *= PENALTY_RATIO
    return [*factors, 1.0]


def seat(system: RigidSystem, contact: Contact, step: str) -> int:
    """Solve the unloaded state ``step`` (a name for the messages); returns Newton iterations.

    Raises:
        ConvergenceError: A solve of the continuation did not converge (the penalties are the
            pairs' own again).
    """
    factors = seating_factors(max(p.penalty for p in contact.pairs))
    if len(factors) == 1:
        return system.solve(step=step)  # the pairs untouched
    logger.info(
        "%s: seated by continuation in the contact penalty (x %s)",
        step,
        ", ".join(f"{f:.3g}" for f in factors),
    )
    its = 0
    try:
        for f in factors:
            contact.scale_penalties(f)
            label = step if f == 1.0 else f"{step} (penalty x {f:.3g})"
            its += system.solve(step=label)
    finally:
        contact.scale_penalties(1.0)
    return its
