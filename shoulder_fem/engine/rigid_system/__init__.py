"""Rigid bodies inside FE models: 6 DOFs per body, tied surfaces, springs, one SNES."""

from shoulder_fem.engine.rigid_system.system import BodyBalance, RigidBody, RigidSystem, Tie

__all__ = ["BodyBalance", "RigidBody", "RigidSystem", "Tie"]
