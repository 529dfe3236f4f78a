"""Which Newton trial states of the shoulder are admissible (the line search's pre-check).

A trial state is admissible when no soft-tissue element is inverted (J = det F > 0) and the
isochoric invariant I1bar stays below :data:`TRIAL_I1BAR_MAX`, checked at the P2 element's ten
nodes and its centroid (``trial_check = "nodes"``, the default) or at the volume forms'
quadrature points, the only points where the laws are evaluated (``"quadrature"``: a P2 element
whose corner folds while its quadrature points stay sound passes; README, "The humerus's swing
on the paper's supports"). Inverted elements, where the laws are not defined, and the
Veronda-Westmann exponential far beyond any physical stretch (I1bar - 3 = 55 gave residuals of
1e55 and then NaN) are thereby never evaluated: the Newton step is halved instead
(:class:`~shoulder_fem.engine.rigid_system.guard.TrialGuard`). The bounds act on trial states
only, never on the equations, and lie far outside the default model's converged states (J in
0.47-2.7, measured at every output: series ``soft_tissue_min_j``, ``soft_tissue_max_j``). The
incompressible option's converged states reach them where it stops on the levels' 25 mm muscles
(a subscapularis element at its insertion's edge; with 8 mm muscles it goes on to the cartilage's
edge: README, "Incompressible soft tissue").
"""

from __future__ import annotations

import basix
import dolfinx
import numpy as np
import ufl
from mpi4py import MPI

from shoulder_fem.engine.fem import JIT_PARAMS
from shoulder_fem.forms.kinematics import (
    deformation_gradient,
    isochoric_invariants,
    right_cauchy_green,
)
from shoulder_fem.meshes import shoulder as S

__all__ = ["TRIAL_CHECKS", "TRIAL_I1BAR_MAX", "SoftTissueCheck", "trial_i1bar_max"]

#: The largest I1bar allowed in a Newton trial state at the muscles' beta = 1 (beta (I1bar - 3)
#: = 100: an exponential factor of 3e43, still far from overflowing).
TRIAL_I1BAR_MAX = 103.0


def trial_i1bar_max(beta: float) -> float:
    """The trial bound on I1bar for the muscles' Veronda-Westmann ``beta``.

    :data:`TRIAL_I1BAR_MAX` up to beta = 1; above, beta (I1bar - 3) = 100, the same largest
    exponential factor.
    """
    return 3.0 + (TRIAL_I1BAR_MAX - 3.0) / max(float(beta), 1.0)


#: The reference points of the check: a tetrahedron's vertices, edge midpoints and centroid.
_VERTICES = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
_EDGES = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
POINTS = np.vstack(
    [_VERTICES, [(_VERTICES[a] + _VERTICES[b]) / 2 for a, b in _EDGES], _VERTICES.mean(axis=0)]
)


#: Where :meth:`SoftTissueCheck.admissible` looks (scene parameter ``trial_check``).
TRIAL_CHECKS = ("nodes", "quadrature")


class SoftTissueCheck:
    """J and I1bar of the soft tissues of ``u`` at :data:`POINTS` (collective).

    Args:
        u: The displacement (P2).
        cell_tags: The mesh's cell tags (soft tissues: :data:`meshes.shoulder.SOFT`).
        guard: Where :meth:`admissible` checks: ``nodes`` (:data:`POINTS`) or ``quadrature``
            (the volume forms' points of degree ``degree``). The recorded ranges
            (:meth:`j_range`, :meth:`i1bar_max`) are at :data:`POINTS` either way.
        degree: The volume forms' quadrature degree (``quadrature`` only).
        i1bar_max: The largest I1bar of an admissible trial state (:func:`trial_i1bar_max`).
    """

    def __init__(
        self,
        u: dolfinx.fem.Function,
        cell_tags: dolfinx.mesh.MeshTags,
        guard: str = "nodes",
        degree: int = 4,
        i1bar_max: float = TRIAL_I1BAR_MAX,
    ):
        if guard not in TRIAL_CHECKS:
            raise ValueError(f"trial_check = {guard!r}: must be one of {', '.join(TRIAL_CHECKS)}")
        mesh = u.function_space.mesh
        self.comm = mesh.comm
        self.i1bar_max_allowed = float(i1bar_max)
        n_owned = mesh.topology.index_map(3).size_local
        soft = np.isin(cell_tags.values, [m.id for m in S.SOFT]) & (cell_tags.indices < n_owned)
        self.cells = np.ascontiguousarray(cell_tags.indices[soft], dtype=np.int32)
        F = deformation_gradient(u)
        # I1bar as the laws evaluate it; J signed (det F), so that an inverted element shows
        i1bar, _, _ = isochoric_invariants(right_cauchy_green(F))
        checked = ufl.as_vector([ufl.det(F), i1bar])
        self.expr = dolfinx.fem.Expression(checked, POINTS, jit_params=JIT_PARAMS)
        self.guard_expr = self.expr
        if guard == "quadrature":
            points, _ = basix.make_quadrature(basix.CellType.tetrahedron, degree)
            self.guard_expr = dolfinx.fem.Expression(checked, points, jit_params=JIT_PARAMS)

    def values(self, guard: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """(J, I1bar) at the owned soft-tissue cells' points (the guard's if ``guard``), flat."""
        if len(self.cells) == 0:
            return np.zeros(0), np.zeros(0)
        expr = self.guard_expr if guard else self.expr
        out = expr.eval(self.cells).reshape(len(self.cells), -1, 2)
        return out[:, :, 0].ravel(), out[:, :, 1].ravel()

    def j_range(self) -> tuple[float, float]:
        """The smallest and largest J over all ranks."""
        J, _ = self.values()
        lo = self.comm.allreduce(float(J.min()) if len(J) else np.inf, op=MPI.MIN)
        hi = self.comm.allreduce(float(J.max()) if len(J) else -np.inf, op=MPI.MAX)
        return lo, hi

    def i1bar_max(self) -> float:
        """The largest I1bar over all ranks (3 undeformed; the trial bound is ``i1bar_max``)."""
        _, i1bar = self.values()
        return self.comm.allreduce(float(i1bar.max()) if len(i1bar) else 3.0, op=MPI.MAX)

    def admissible(self) -> bool:
        """Whether the current state may be a Newton trial state (same on every rank)."""
        J, i1bar = self.values(guard=True)
        with np.errstate(invalid="ignore"):
            ok = bool(np.all((J > 0.0) & (i1bar < self.i1bar_max_allowed)))
        return bool(self.comm.allreduce(ok, op=MPI.LAND))

    def __call__(self) -> bool:
        """:meth:`admissible` (the callable that :class:`RigidSystem` takes)."""
        return self.admissible()
