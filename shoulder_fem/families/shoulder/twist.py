"""The humeral twist as a controlled measure: its value and gradient for the Newton system.

The rotation angle drives the stepping (:mod:`.stepping`): each step solves for the actuator's
travel that gives the target twist, so the twist enters the Newton system with its gradient
(:class:`~shoulder_fem.engine.rigid_system.control.MeasureGradient`). Decoupled part 1: the twist
of the rigid humerus's rotation, a function of its rotation DOFs alone. Coupled: the twist of the
best-fit rotation of the deformable humerus's nodes, a function of their displacements.
"""

from __future__ import annotations

from collections.abc import Callable

import dolfinx
import numpy as np

from shoulder_fem.engine.rigid_system import RigidBody
from shoulder_fem.engine.rigid_system.control import MeasureGradient
from shoulder_fem.families.shoulder.geometry import best_fit_twist, twist_angle, twist_gradient

__all__ = ["fitted_twist", "rigid_twist"]


def rigid_twist(body: RigidBody, index: int, axis: np.ndarray) -> Callable[[bool], MeasureGradient]:
    """The twist (rad) of rigid ``body`` (body ``index`` of its system) about the unit ``axis``."""

    def measure(with_gradient: bool) -> MeasureGradient:
        out = MeasureGradient(twist_angle(body.rotation, axis))
        if with_gradient:
            out.bodies[index] = np.concatenate([np.zeros(3), twist_gradient(body.rotation, axis)])
        return out

    return measure


def fitted_twist(
    u: dolfinx.fem.Function, nodes: np.ndarray, axis: np.ndarray
) -> Callable[[bool], MeasureGradient]:
    """The twist (rad) of the best-fit rotation of ``u``'s owned ``nodes`` (block indices)."""
    V = u.function_space
    comm = V.mesh.comm
    n_owned = V.dofmap.index_map.size_local
    nodes = np.asarray(nodes)
    nodes = nodes[nodes < n_owned]
    X = V.tabulate_dof_coordinates()[nodes]

    def measure(with_gradient: bool) -> MeasureGradient:
        x = X + u.x.array.reshape(-1, 3)[nodes]
        value, grad = best_fit_twist(X, x, axis, comm, with_gradient)
        out = MeasureGradient(value)
        if grad is not None:
            out.fe = np.zeros(3 * n_owned)
            out.fe.reshape(-1, 3)[nodes] = grad
        return out

    return measure
