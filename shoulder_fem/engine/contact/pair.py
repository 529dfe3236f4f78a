"""A contact pair (slave surface, master, normal law and friction) and its pressure law."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from shoulder_fem.engine.contact.masters import ContactError, MeshSurface, RigidMaster


@dataclass(frozen=True)
class ContactPair:
    """One slave surface against one master.

    Attributes:
        name: Used in outputs (``<name>_force`` ...).
        slave: Facet tag values of the slave surface.
        master: A :class:`~shoulder_fem.engine.contact.masters.MeshSurface` or any rigid
            master (:class:`~shoulder_fem.engine.contact.masters.RigidMaster`: a ``Plane``, a
            ``Sphere`` or another object with the same ``project`` method).
        penalty: Penalty stiffness eps (Pa/m).
        method: ``penalty`` or ``augmented`` (augmented Lagrangian, Uzawa iterations).
        gap_tolerance: Largest penetration accepted by the augmented Lagrangian (m).
        friction: Coulomb coefficient mu (0: frictionless).
        slip_regularization: Regularisation slip e_s of the friction law (m).
        candidates: Master triangles tested exactly per slave point (nearest centroids).
        search_depth: Against a mesh master, the largest penetration (m) still taken as
            contact; a point deeper than this is paired with the far side of a thick or
            curved master (or a slave face looking away from it: the outer face of a muscle
            over a bone) and carries no pressure. Keep it well above the penetrations the
            penalty allows and below the thickness of the slave body.
        smoothing: Penalty only: half width s (m) of a C1 transition of the pressure law
            around g = 0, p = eps (s - g)^2 / (4 s) for |g| < s (p = eps <-g> outside). A point
            that crosses g = 0 then changes the pressure and the tangent gradually: where many
            points graze a sliding faceted surface, Newton no longer cycles between active
            sets. 0: the plain penalty law.
        curved: Lift the mid-edge nodes of both P2 surfaces onto the smooth surfaces through
            their vertices and vertex normals (:mod:`~.curved`): the contact then sees curved
            facets where the mesh has flat ones (no effect on P1 surfaces or a rigid master).
    """

    name: str
    slave: tuple[int, ...]
    master: RigidMaster | MeshSurface
    penalty: float
    method: str = "penalty"
    gap_tolerance: float = 1e-6
    friction: float = 0.0
    slip_regularization: float = 1e-6
    candidates: int = 12
    search_depth: float = math.inf
    smoothing: float = 0.0
    curved: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "slave", tuple(int(t) for t in np.atleast_1d(self.slave)))
        where = f"contact pair {self.name!r}"
        if not (np.isfinite(self.penalty) and self.penalty > 0):
            raise ContactError(f"{where}: penalty = {self.penalty!r} Pa/m, must be > 0")
        if self.method not in ("penalty", "augmented"):
            raise ContactError(
                f"{where}: method = {self.method!r}, must be 'penalty' or 'augmented'"
            )
        if not self.gap_tolerance > 0:
            raise ContactError(f"{where}: gap_tolerance = {self.gap_tolerance!r} m, must be > 0")
        if not self.friction >= 0:
            raise ContactError(f"{where}: friction = {self.friction!r}, must be >= 0")
        if self.friction > 0 and not self.slip_regularization > 0:
            raise ContactError(
                f"{where}: slip_regularization = {self.slip_regularization!r} m, must be > 0"
            )
        if not self.smoothing >= 0 or (self.smoothing > 0 and self.method != "penalty"):
            raise ContactError(
                f"{where}: smoothing = {self.smoothing!r} m, must be >= 0 (penalty method only)"
            )
        if not self.search_depth > 0:
            raise ContactError(f"{where}: search_depth = {self.search_depth!r} m, must be > 0")
        if not isinstance(self.master, (MeshSurface, RigidMaster)):
            raise ContactError(
                f"{where}: unknown master type {type(self.master).__name__} (expected a "
                "MeshSurface or a rigid master with a project(x) method)"
            )


def penalty_law(depth: np.ndarray, penalty: float, smoothing: float = 0.0):
    """Pressure (Pa) and its derivative dp/d(depth) (Pa/m) at penetrations ``depth`` (m).

    ``penalty`` <depth> for ``smoothing`` = 0; otherwise the C1 law of
    :attr:`ContactPair.smoothing` (equal to it beyond ``smoothing`` on either side).
    """
    d = np.asarray(depth, dtype=float)
    if smoothing == 0.0:
        return penalty * np.maximum(d, 0.0), np.where(d > 0, penalty, 0.0)
    s = smoothing
    mid = np.clip(d + s, 0.0, 2 * s)
    p = np.where(d > s, penalty * d, penalty * mid**2 / (4 * s))
    k = np.where(d > s, penalty, penalty * mid / (2 * s))
    return p, k


def normal_pressure(pair: ContactPair, gap: np.ndarray, lam: np.ndarray):
    """Normal pressure (Pa) and its stiffness -dp/dg (Pa/m) of ``pair`` at gaps ``gap`` (m).

    The penalty law (:func:`penalty_law`) or, for the augmented Lagrangian, <lam - eps g> with
    the multipliers ``lam`` (Pa) at the same points.
    """
    if pair.method == "augmented":
        p = np.maximum(lam - pair.penalty * gap, 0.0)
        k = np.where(p > 0, pair.penalty, 0.0)
    else:
        p, k = penalty_law(-gap, pair.penalty, pair.smoothing)
    return p, k
