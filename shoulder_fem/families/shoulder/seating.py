"""The unloaded solve of the shoulder (the joint seating), by continuation where it needs one.

At rest the faceted cartilage layers overlap a little, so the first Newton residual is the
penalty times that overlap: about 240 N at ``coarse`` with 5 MPa/mm (the earlier default),
which Newton resolves in 9 iterations. Ten times stiffer, the first residual is 2 400 N and
Newton cycles between active sets without converging (measured at 50 MPa/mm: no convergence in 60
iterations). The same equilibrium is reached by a continuation: each pair's penalty scaled
down to :data:`SEATING_PENALTY` for the stiffest (the glenohumeral pair's), then raised by
:data:`PENALTY_RATIO` per solve up to its own, each solve starting from the one before. Only
the path changes: the final solve is the scene's own (tested: the seated state equals a
direct solve's where that converges).

The same holds for nearly incompressible soft tissue (``soft_tissue_formulation =
incompressible``): at kappa/mu = 1000 the first Newton step of the seating strains the tissue
by the square of its rotations, and kappa times that (240 N -> 8 900 N at ``coarse``, coupled;
the tangent agrees with finite differences to 3e-5) sends Newton away: no convergence in 15
iterations (part 1 alike). Seated at kappa/mu = :data:`SEATING_BULK_RATIO` first, then at 10x
per solve up to the scene's (coarse: 8, 3 and 2 iterations for 10, 100, 1000).
"""

from __future__ import annotations

import logging

from shoulder_fem.engine.contact import Contact
from shoulder_fem.engine.rigid_system import RigidSystem
from shoulder_fem.families.shoulder.newton import solve_with_fallback

__all__ = [
    "BULK_RATIO_STEP",
    "PENALTY_RATIO",
    "SEATING_BULK_RATIO",
    "SEATING_PENALTY",
    "bulk_factors",
    "seat",
    "seating_factors",
]

logger = logging.getLogger(__name__)

#: The largest penalty (Pa/m) the seating is solved with directly: 5 MPa/mm, which seats in 9
#: Newton iterations at ``coarse`` (the default 60 MPa/mm: 5/60, 0.25, 0.75, then 1).
SEATING_PENALTY = 5e9
#: The penalty's growth from one continuation solve to the next (measured at ``coarse``,
#: 50 MPa/mm: 8, 4 and 3 iterations at 0.1, 0.3 and 0.9 of it, then the full penalty).
PENALTY_RATIO = 3.0
#: The largest kappa/mu of the soft tissue the seating is solved with directly (measured at
#: ``coarse``: 10 and 100 seat in 8 iterations, 1000 not in 15).
SEATING_BULK_RATIO = 10.0
#: The bulk modulus's growth from one continuation solve to the next.
BULK_RATIO_STEP = 10.0


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


def bulk_factors(ratio: float | None) -> list[float]:
    """The bulk-modulus factors of the seating solves for the soft tissue's kappa/mu ``ratio``.

    ``[1.0]`` without one (compressible tissue) or up to :data:`SEATING_BULK_RATIO`; above it,
    the factors from ``SEATING_BULK_RATIO / ratio`` up by :data:`BULK_RATIO_STEP`, then 1.
    """
    if ratio is None:
        return [1.0]
    factors, f = [], SEATING_BULK_RATIO / ratio
    while f < 1.0 - 1e-12:
        factors.append(f)
        f *= BULK_RATIO_STEP
    return [*factors, 1.0]


def seat(system: RigidSystem, contact: Contact, step: str, bulk_ratio: float | None = None) -> int:
    """Solve the unloaded state ``step`` (a name for the messages); returns Newton iterations.

    ``bulk_ratio``: the soft tissue's kappa/mu when it is nearly incompressible (the system's
    ``volumetric`` terms), else ``None``. The bulk modulus is raised first (at the penalties'
    first continuation factor), then the penalties.

    Raises:
        ConvergenceError: A solve of the continuation did not converge (the penalties and bulk
            moduli are their own again).
    """
    volumetric = system.volumetric
    bulk = bulk_factors(bulk_ratio if volumetric is not None else None)
    if len(bulk) == 1:
        return _seat_penalties(system, contact, step)
    logger.info(
        "%s: seated by continuation in the soft tissue's bulk modulus (x %s)",
        step,
        ", ".join(f"{f:.3g}" for f in bulk),
    )
    its = 0
    first = seating_factors(max(p.penalty for p in contact.pairs))[0]
    try:
        contact.scale_penalties(first)
        for f in bulk[:-1]:
            volumetric.scale_bulk(f)
            its += _solve(system, f"{step} (bulk modulus x {f:.3g})")
    finally:
        volumetric.scale_bulk(1.0)
        contact.scale_penalties(1.0)
    return its + _seat_penalties(system, contact, step)


def _seat_penalties(system: RigidSystem, contact: Contact, step: str) -> int:
    """The seating's continuation in the contact penalty (:func:`seating_factors`)."""
    factors = seating_factors(max(p.penalty for p in contact.pairs))
    if len(factors) == 1:
        return _solve(system, step)  # the pairs untouched
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
            its += _solve(system, label)
    finally:
        contact.scale_penalties(1.0)
    return its


def _solve(system: RigidSystem, step: str) -> int:
    """One solve of the seating, retried with the line search where full steps fail.

    Full Newton steps from the unseated state can overshoot: with the 4 distal elements at
    50 N/mm each the first step took the residual from 240 to 5 300 N and 15 iterations did
    not converge (coarse, part 1); with the ``l2`` line search 13 did.
    """
    return solve_with_fallback(system, step, system.snapshot(), divergence_tolerance=-1.0)
