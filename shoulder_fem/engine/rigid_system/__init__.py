"""Rigid bodies inside FE models: 6 DOFs per body, tied surfaces, springs, one SNES.

The reduced unknowns are the free FE displacement DOFs and six DOFs per rigid body; tied nodes
follow their body exactly through a prolongation P. ``bodies`` (the user's objects), ``layout``
(numbering and P), ``terms`` (the rigid rows), ``dynamics`` (the time step's state),
``deformable`` (FE assembly), ``problem`` (residual and Jacobian) and ``system`` (the driver).
"""

from shoulder_fem.engine.rigid_system.bodies import BodyBalance, RigidBody, Tie
from shoulder_fem.engine.rigid_system.system import RigidSystem

__all__ = ["BodyBalance", "RigidBody", "RigidSystem", "Tie"]
