"""Flexible elements: linear springs between points of rigid bodies and the ground.

A spring joins point ``a`` of a body to point ``b`` of another body or of the ground (the
paper's "flexible elements": the scapula hangs on 21 of them). Its energy is

    E = k/2 (ℓ - L0)²,     ℓ = |p_a - p_b|,

with stiffness k (N/m) and rest length L0 (m). A tension-only spring carries no force while
ℓ < L0 (a ligament or a muscle's passive line). Points are given in the reference
configuration (m); on a rigid body they follow its motion, on the ground they stay put.

This module is pure numpy: :func:`spring_response` returns the force and the consistent tangent
of one spring at given end positions; :class:`~shoulder_fem.engine.rigid_system.RigidSystem`
maps them onto the bodies' six DOFs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

#: Name of the ground in :attr:`Spring.body_b` (a fixed point in space).
GROUND = "ground"

__all__ = ["GROUND", "Spring", "SpringResponse", "spring_response"]


@dataclass(frozen=True)
class Spring:
    """A linear spring between a point of a body and the ground or a point of another body.

    Attributes:
        name: Unique name (used in outputs).
        body_a: Name of the body carrying end a.
        point_a: Reference position of end a (m), shape (3,).
        body_b: Name of the body carrying end b, or :data:`GROUND`.
        point_b: Reference position of end b (m), shape (3,) (a fixed point for the ground).
        stiffness: k (N/m), > 0.
        rest_length: L0 (m), >= 0. ``None`` means the reference distance of the two points
            (no force in the reference configuration).
        tension_only: No force while the spring is shorter than its rest length.
    """

    name: str
    body_a: str
    point_a: tuple[float, float, float]
    body_b: str
    point_b: tuple[float, float, float]
    stiffness: float
    rest_length: float | None = None
    tension_only: bool = False
    _length0: float = field(init=False, repr=False, default=0.0)

    def __post_init__(self) -> None:
        pa = np.asarray(self.point_a, dtype=float)
        pb = np.asarray(self.point_b, dtype=float)
        if pa.shape != (3,) or pb.shape != (3,) or not np.all(np.isfinite(np.r_[pa, pb])):
            raise ValueError(f"spring '{self.name}': point_a and point_b must be finite 3-vectors")
        if not (math.isfinite(self.stiffness) and self.stiffness > 0):
            raise ValueError(
                f"spring '{self.name}': stiffness must be > 0 N/m, got {self.stiffness}"
            )
        if self.body_a == self.body_b:
            raise ValueError(f"spring '{self.name}': both ends on '{self.body_a}'")
        length0 = float(np.linalg.norm(pa - pb))
        rest = length0 if self.rest_length is None else float(self.rest_length)
        if not (math.isfinite(rest) and rest >= 0):
            raise ValueError(f"spring '{self.name}': rest_length must be >= 0 m, got {rest}")
        if rest == 0.0 and length0 == 0.0:
            raise ValueError(f"spring '{self.name}': zero length and zero rest length")
        object.__setattr__(self, "point_a", tuple(pa))
        object.__setattr__(self, "point_b", tuple(pb))
        object.__setattr__(self, "rest_length", rest)
        object.__setattr__(self, "_length0", length0)


@dataclass(frozen=True)
class SpringResponse:
    """State of one spring at given end positions.

    Attributes:
        length: Current length ℓ (m).
        tension: Axial force N = k (ℓ - L0) (N), positive in tension (0 if slack and
            tension-only).
        gradient: dE/dp_a (N), shape (3,): the force the spring exerts on end a is ``-gradient``
            and on end b ``+gradient``.
        tangent: d²E/dp_a² (N/m), shape (3, 3): ``k n nᵀ + (N/ℓ)(I - n nᵀ)``.
    """

    length: float
    tension: float
    gradient: FloatArray
    tangent: FloatArray


def spring_response(spring: Spring, p_a: ArrayLike, p_b: ArrayLike) -> SpringResponse:
    """Force and consistent tangent of ``spring`` with ends at ``p_a`` and ``p_b`` (m).

    With d = p_a - p_b, ℓ = |d|, n = d/ℓ and N = k(ℓ - L0): dE/dp_a = N n and
    d²E/dp_a² = k n nᵀ + (N/ℓ)(I - n nᵀ) (the second term is the geometric stiffness of a
    pre-stressed spring). A slack tension-only spring gives zero force and zero tangent.
    """
    d = np.asarray(p_a, dtype=float) - np.asarray(p_b, dtype=float)
    length = float(np.linalg.norm(d))
    if length == 0.0:
        raise ValueError(f"spring '{spring.name}': its two ends coincide (zero length)")
    n = d / length
    tension = spring.stiffness * (length - spring.rest_length)
    if spring.tension_only and tension < 0.0:
        return SpringResponse(length, 0.0, np.zeros(3), np.zeros((3, 3)))
    nn = np.outer(n, n)
    tangent = spring.stiffness * nn + (tension / length) * (np.eye(3) - nn)
    return SpringResponse(length, tension, tension * n, tangent)
