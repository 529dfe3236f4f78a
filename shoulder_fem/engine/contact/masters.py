"""Contact masters: what a slave surface presses on.

A master is either a tagged surface of the FE mesh (:class:`MeshSurface`, deformable, searched
as triangles) or a rigid body given analytically: any object with the :class:`RigidMaster`
``project`` method (:class:`Plane` and :class:`Sphere` here). A new rigid master needs no change
to the assembly, only that method.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np


class ContactError(ValueError):
    """A contact definition that cannot work (unknown surface, wrong element, bad value)."""


@runtime_checkable
class RigidMaster(Protocol):
    """A rigid master given analytically: anything with this :meth:`project`."""

    def project(
        self, x: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        """Closest points, normals, gaps and normal derivatives dn/dx for points ``x``.

        Args:
            x: Current positions of the slave's contact points (m, (q, 3)).

        Returns:
            (xm, n, g, dndx): the closest master points (m, (q, 3)), the master's unit normals
            there, pointing out of the rigid solid towards the slave ((q, 3)), the signed gaps
            g = (x - xm) . n (m, (q,), negative = penetration) and the derivatives of the normal
            with respect to x (1/m, (q, 3, 3)), or None where the normal is constant.
        """
        ...


@dataclass(frozen=True)
class Plane:
    """A rigid plane; ``normal`` points out of the rigid solid (towards the slave).

    Attributes:
        point: A point of the plane (m).
        normal: Outward normal (normalised on creation).
    """

    point: tuple[float, float, float]
    normal: tuple[float, float, float]

    def __post_init__(self) -> None:
        n = np.asarray(self.normal, dtype=float)
        if n.shape != (3,) or not np.linalg.norm(n) > 0:
            raise ContactError(f"Plane normal {self.normal!r}: must be a non-zero 3-vector")
        object.__setattr__(self, "normal", tuple(n / np.linalg.norm(n)))

    def project(self, x: np.ndarray):
        """Closest points, normals, gaps and normal derivatives dn/dx for points ``x``."""
        n = np.broadcast_to(np.asarray(self.normal), x.shape)
        g = (x - np.asarray(self.point)) @ np.asarray(self.normal)
        return x - g[:, None] * n, np.array(n), g, None


@dataclass(frozen=True)
class Sphere:
    """A rigid sphere: a ball (slave outside) or, with ``concave``, a socket (slave inside).

    Attributes:
        centre: Centre (m).
        radius: Radius (m).
        concave: True for a spherical cavity (the rigid solid is outside the sphere).
    """

    centre: tuple[float, float, float]
    radius: float
    concave: bool = False

    def __post_init__(self) -> None:
        if not (isinstance(self.radius, (int, float)) and self.radius > 0):
            raise ContactError(f"Sphere radius {self.radius!r} m: must be > 0")

    def project(self, x: np.ndarray):
        """Closest points, normals, gaps and normal derivatives dn/dx for points ``x``."""
        d = x - np.asarray(self.centre)
        r = np.linalg.norm(d, axis=1)
        r = np.where(r > 0, r, 1e-300)
        e = d / r[:, None]
        proj = np.eye(3)[None] - np.einsum("qi,qj->qij", e, e)
        xm = np.asarray(self.centre) + self.radius * e
        if self.concave:
            return xm, -e, self.radius - r, -proj / r[:, None, None]
        return xm, e, r - self.radius, proj / r[:, None, None]


@dataclass(frozen=True)
class MeshSurface:
    """A deformable master: the facets of the FE mesh with these tag values."""

    tags: tuple[int, ...]

    def __post_init__(self) -> None:
        object.__setattr__(self, "tags", tuple(int(t) for t in np.atleast_1d(self.tags)))
