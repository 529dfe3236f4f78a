"""The decoupled method's part 1 on a driven body: the hub's motion as the floating frame.

Owns :class:`FloatingFrame`: the frame's body-frame angular velocity Ω, angular acceleration Ω̇
and the acceleration a_G of the centre of mass, as form constants set from the prescribed motion
at each time, and GM, the position relative to G on which the rigid-frame inertia acts. The
motion is prescribed, so the paper's step 1 (eq. 10) is the motion itself.
"""

from __future__ import annotations

import numpy as np
import ufl

from shoulder_fem.engine.fem import constant
from shoulder_fem.families.driven_body.model import DrivenBody


class FloatingFrame:
    """The hub's rotation about the fixed spin axis, seen from the body (rotating) frame.

    Args:
        model: the driven body.
        x_g: its centre of mass G (m), body frame (= inertial at t = 0).

    Attributes:
        omega: body-frame angular velocity Ω = ω e (rad/s).
        domega: body-frame angular acceleration Ω̇ = ω̇ e (rad/s²).
        omega2: ω² (rad²/s²), the scale of the centrifugal prestress.
        a_g: body-frame acceleration of G (m/s²).
        gm: GM = X − G (UFL, m).
    """

    def __init__(self, model: DrivenBody, x_g: np.ndarray):
        mesh = model.mesh
        self.motion = model.motion
        self.axis = model.axis
        self.x_g = x_g
        self.omega = constant(mesh, np.zeros(3))
        self.domega = constant(mesh, np.zeros(3))
        self.omega2 = constant(mesh, 0.0)
        self.a_g = constant(mesh, np.zeros(3))
        self.gm = ufl.SpatialCoordinate(mesh) - constant(mesh, x_g)

    def set_rate(self, rate: float, rate_dot: float) -> None:
        """Set Ω, Ω̇ and ω² from the spin rate ω (rad/s) and its rate ω̇ (rad/s²); a_G untouched."""
        axis = self.axis
        self.omega.value[:], self.domega.value[:], self.omega2.value = (
            rate * axis,
            rate_dot * axis,
            rate**2,
        )

    def move_to(self, t: float) -> None:
        """Set the frame to the prescribed motion at time ``t`` (s): Ω, Ω̇, ω² and a_G."""
        self.set_rate(self.motion.rate(t), self.motion.acceleration(t))
        wv, dwv, x_g = self.omega.value, self.domega.value, self.x_g
        self.a_g.value[:] = np.cross(dwv, x_g) + np.cross(wv, np.cross(wv, x_g))  # G turns about O

    def save_rates(self) -> tuple[np.ndarray, np.ndarray, float]:
        """A copy of Ω, Ω̇ and ω² (to put back with :meth:`restore_rates`)."""
        return self.omega.value.copy(), self.domega.value.copy(), float(self.omega2.value)

    def restore_rates(self, saved: tuple[np.ndarray, np.ndarray, float]) -> None:
        """Put back Ω, Ω̇ and ω² from :meth:`save_rates`."""
        self.omega.value[:], self.domega.value[:], self.omega2.value = saved
