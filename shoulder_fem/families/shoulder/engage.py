"""Engaging the open unloaded joint: the plate pulled by travel until the joint carries load.

With curved articular surfaces (``contact_surfaces = curved``) the unloaded joint is open: the
cartilages touch at a point and nothing presses them together, and the muscles are slack. The
angle-controlled Newton system is then nearly singular: its first step from the open joint
(coupled, ``coarse``, curved surfaces at 100 MPa/mm) moved the humerus 0.3 m and turned it by
13 deg, the scapula by 68 deg, and the step was cut back 3 times before 0.17 deg converged
(part 1: 15 iterations without converging, then 30 with the ``l2`` line search). Controlled
by the plate's travel instead, the same states are reached in 4-7 Newton iterations each
(measured: 0.02 to 2.54 mm of travel in 7 solves, 0.008 to 1.58 deg, none failed).

So :func:`engage` raises the travel from :data:`ENGAGE_TRAVEL`, doubled after each converged
solve and halved after a failed one, until the glenohumeral normal force reaches
:data:`ENGAGE_FORCE`; then the angle is the control again, from the angle reached. Every state
on the way is an equilibrium of the same model under the same loads: only the path to the
first angle step changes (tested: the state at 3 deg is the one reached without it). A joint
that carries :data:`ENGAGE_FORCE` at rest is left as it is. (The curved surfaces' unloaded
joint carries 4e-4 N at ``medium`` and 9e-5 N at ``paper``: an engagement only at exactly 0 N
skipped them, and their first angle step needed the ``l2`` retry.)
"""

from __future__ import annotations

import logging
import math

import numpy as np

from shoulder_fem.engine.rigid_system.control import MeasureGradient
from shoulder_fem.engine.solver import ConvergenceError
from shoulder_fem.families.shoulder.newton import solve_with_fallback

__all__ = [
    "ENGAGE_FORCE",
    "ENGAGE_LIMIT",
    "ENGAGE_STOP",
    "ENGAGE_TRAVEL",
    "TRAVEL_SCALE",
    "angle_now",
    "engage",
    "joint_force",
]

logger = logging.getLogger(__name__)

#: The glenohumeral normal force (N) that ends the engagement (the flat facets' corners carry
#: about 1 N at rest at ``coarse``).
ENGAGE_FORCE = 1.0
#: The engagement ends once the twist reaches this fraction of the first angle the stepping
#: lands on, and a solve past :data:`ENGAGE_LIMIT` of it is taken back with half the travel.
#: A quarter was too early with the incompressible cartilage: at ``coarse`` with a 3 deg first
#: output it handed over at 0.79 deg with 0.71 N on the joint, and the coupled angle step from
#: there failed in both line searches (cut back once; measured).
ENGAGE_STOP = 0.5
#: See :data:`ENGAGE_STOP`.
ENGAGE_LIMIT = 0.75
#: The engagement's first increment of the plate's travel (m).
ENGAGE_TRAVEL = 2e-5
#: Residual of the travel equation per metre of travel error (N/m): with ``snes_atol`` = 1e-3
#: N the travel is hit to 1 nm.
TRAVEL_SCALE = 1e6


def joint_force(contact) -> float:
    """The glenohumeral normal force (N; collective)."""
    return contact.resultants()["glenohumeral"]["normal_force"]


def angle_now(stepper) -> float:
    """The humeral twist at the current state (rad; collective)."""
    return stepper.measure(False).value


def engage(stepper, first: float) -> str | None:
    """Engage an open joint by travel, then hand back to the angle control (collective).

    Args:
        stepper: The :class:`~.stepping.AngleStepper`, its angle control set (after its
            ``start``); its ``theta``, ``tangent`` and ``log`` (``steps``,
            ``engaging_steps``, ``engaged_angle``) are updated.
        first: The first angle the stepping must land on (rad, an output or the final
            angle). The engagement also ends from :data:`ENGAGE_STOP` (half) of it on, and a
            solve that passes :data:`ENGAGE_LIMIT` of it is taken back with half the travel: the
            angle steps always have the way to it (``--set final_angle=1deg`` would otherwise
            have been engaged past it, to 1.58 deg at ``coarse``).

    Returns:
        None, or why it stopped (more than 2 x ``max_cutbacks`` failed solves; the state is the
        last converged one).
    """
    rest = joint_force(stepper.contact)
    if rest >= ENGAGE_FORCE:
        return None
    logger.info("%s: engaging the joint by travel (%.3g N at rest)", stepper.label, rest)
    system, log = stepper.system, stepper.log
    twist = system.control
    gradient = {twist.body: np.r_[twist.direction, 0.0, 0.0, 0.0]}

    def travel(with_gradient: bool) -> MeasureGradient:
        return MeasureGradient(stepper.travel(), bodies=gradient)

    control = system.set_control(stepper.actuator.name, twist.direction, travel, TRAVEL_SCALE)
    control.origin = twist.origin  # the travel is counted from the unloaded plate
    delta, fails = ENGAGE_TRAVEL, 0
    while joint_force(stepper.contact) < ENGAGE_FORCE and angle_now(stepper) < ENGAGE_STOP * first:
        snap = system.snapshot()
        control.target = stepper.travel() + delta
        name = f"{stepper.label} engaging, travel {control.target * 1e3:.3f} mm"
        try:
            its = solve_with_fallback(system, name, snap, None, log)
        except ConvergenceError as err:
            system.restore(snap)
            log.failed_steps += 1
            fails += 1
            if fails > 2 * stepper.max_cut:
                return (
                    f"{stepper.label}: stopped at 0 deg: the open unloaded joint did not engage "
                    f"towards {control.target * 1e3:.4f} mm of travel in {fails} tries "
                    f"({err.reason})"
                )
            delta *= 0.5
            continue
        if angle_now(stepper) > ENGAGE_LIMIT * first:  # too far: taken back, not a failure
            system.restore(snap)
            log.newton_iterations += its
            delta *= 0.5
            continue
        stepper.contact.commit()
        log.steps += 1
        log.engaging_steps += 1
        log.newton_iterations += its
        delta *= 2.0
        logger.info(
            "%s: engaging: travel %.4f mm, angle %.4f deg, joint force %.3g N, %d Newton "
            "iterations",
            stepper.label,
            stepper.travel() * 1e3,
            math.degrees(angle_now(stepper)),
            joint_force(stepper.contact),
            its,
        )
    angle = system.set_control(stepper.actuator.name, twist.direction, twist.measure, twist.scale)
    angle.origin = control.origin
    stepper.theta = log.engaged_angle = angle.target
    if stepper.tangent is not None:
        stepper.tangent.destroy()
    stepper.tangent = system.control_tangent(refresh=True)
    return None
