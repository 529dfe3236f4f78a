"""Newton steps of stiff regions of the deformable body whose rigid part is a finite rotation.

A Newton step is linear in the nodal displacements: a region that turns by an angle θ as a
whole moves by ω × r, and its points at a distance r from its centre land off the rotated
positions by about θ² r / 2 -- a strain of θ²/2 all over the region, which in stiff bone is a
large stress. Measured on the coupled shoulder at ``coarse`` (the paper's supports, the step
to 11 deg): the Newton step turned the scapula by 1.0 deg about the vertical (its rigid fit
leaves 0.02 mm of a 2 mm step), and the residual went from 91 N to 3 625 N at the full step,
all of it on the nodes of the scapular blade 50-90 mm from the joint, quadratically in the
step length (908 N at half of it); the tangent agreed with finite differences to 7e-5. The
solve then needed the ``l2`` line search and 45 iterations (coarse, 0-60 deg: 310 Newton
iterations in 43 steps; with the correction 120 in 27; at ``medium`` 209 in 39 steps, one
failed, against 122 in 25, two failed: early steps along the swing still fail once or twice).

:class:`RigidRegions` fits each region's share of a Newton step with a rigid motion
t + ω × r (least squares about the region's current centroid, over its free nodes on every
rank) and replaces the linear rotation by the finite one, ``d_i += (R(ω) - I - hat ω) r_i``,
for its free nodes and for the reference points of the rigid bodies tied to it (the spring
plates: their own rotations are already finite; a plate left on the linear path tears the
bone around its patch). At the step above the residual at the full step falls to 298 N. The
change is second order in the step, so Newton's quadratic convergence and the converged states
are unchanged; only the iterates stay nearer the equilibrium path. Applied by the trial-state
guard to every Newton step (:class:`~.guard.TrialGuard`, ``correct``), before the line search:
a line search that shortens the step scales the correction with it (exact at the full step
only; the error is second order in the shortening). Predictors need none: a second-order
predictor's curvature term already holds the rotation's θ² r / 2. Tried and not kept: a
limit of 5 deg per Newton step on a region's rotation (the coupled run's early failing step
at ``coarse`` asked for 20 deg, then, limited, for 34-45 deg again: the same cut-back).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from shoulder_fem.engine.rigid_system.layout import ReducedLayout
from shoulder_fem.engine.so3 import exp_so3, hat

__all__ = ["RigidRegions", "rigid_fit"]


def rigid_fit(p: np.ndarray, d: np.ndarray, comm: MPI.Comm) -> tuple[np.ndarray, np.ndarray]:
    """The least-squares rigid motion of nodal steps ``d`` at positions ``p`` (collective).

    Minimises Σ |d_i - t - ω × (p_i - c)|² over every rank's nodes, c their centroid.

    Returns:
        (c, ω): the centroid (m) and the rotation vector (rad); ω = 0 for fewer than 3 nodes.
    """
    n = comm.allreduce(len(p), op=MPI.SUM)
    if n < 3:
        return np.zeros(3), np.zeros(3)
    c = comm.allreduce(p.sum(axis=0), op=MPI.SUM) / n
    r = p - c
    A = comm.allreduce(
        np.einsum("ni,ni->", r, r) * np.eye(3) - np.einsum("ni,nj->ij", r, r), op=MPI.SUM
    )
    b = comm.allreduce(np.cross(r, d).sum(axis=0), op=MPI.SUM)
    return c, np.linalg.solve(A, b)


class RigidRegions:
    """The stiff regions of a deformable body: the rotations of their Newton steps made finite.

    Args:
        layout: The system's reduced layout (free nodes, their coordinates, the tied nodes).
        bodies: The system's rigid bodies (their reference points).
        regions: Per region, local node indices (owned and ghost). Its free nodes are fitted
            and corrected; a body with a tied node in the region is corrected with it, unless
            its motion is prescribed.
    """

    def __init__(self, layout: ReducedLayout, bodies: Sequence, regions: Sequence[np.ndarray]):
        self.comm = layout.comm
        self.layout = layout
        self.bodies = list(bodies)
        free = layout.free_nodes
        regions = [np.asarray(r) for r in regions]
        #: Per region, the positions of its nodes in the free block (3 entries each).
        self.index = [np.flatnonzero(np.isin(free, r)) for r in regions]
        self.X = [layout.X[free[i]] for i in self.index]
        #: Per region, the bodies tied to it.
        self.tied = []
        for r in regions:
            mine = [int(np.isin(t, r).any()) for t in layout.tied_nodes]
            tied = np.array(mine, dtype=np.int64)
            self.comm.Allreduce(MPI.IN_PLACE, tied, op=MPI.MAX)
            # a prescribed body keeps its prescription (its rows are identities)
            tied[np.array([b.prescribed for b in self.bodies], dtype=bool)] = 0
            self.tied.append(np.flatnonzero(tied))

    def correct(self, x: np.ndarray, d: np.ndarray) -> float:
        """Add each region's finite-rotation correction to the step ``d`` in place.

        Args:
            x: The current state as this rank's block of the reduced vector (the free nodes'
                displacements, then on rank 0 the bodies' translations and rotation vectors).
            d: A step of the same entries, changed in place.

        Returns:
            The largest rotation fitted (rad), the same on every rank (collective).
        """
        lay = self.layout
        n = lay.n_free_local
        u = x[:n].reshape(-1, 3)
        dn = d[:n].reshape(-1, 3)
        largest = 0.0
        for idx, X, tied in zip(self.index, self.X, self.tied, strict=True):
            p = X + u[idx]
            c, omega = rigid_fit(p, dn[idx], self.comm)
            theta = float(np.linalg.norm(omega))
            largest = max(largest, theta)
            if theta == 0.0:
                continue
            Q = exp_so3(omega) - np.eye(3) - hat(omega)
            dn[idx] += (p - c) @ Q.T
            if self.comm.rank == 0:  # the bodies' DOFs: (t, φ) each, after the free block
                for b in tied:
                    t = slice(n + 6 * b, n + 6 * b + 3)
                    d[t] += Q @ (self.bodies[b].reference_point + x[t] - c)
        return largest

    def precheck(self, x: PETSc.Vec, y: PETSc.Vec) -> bool:
        """Correct the Newton step ``y`` (trial ``x - y``) in place; True if it changed.

        The trial-state guard's ``correct`` (collective).
        """
        yv = y.array  # a view of the owned entries
        d = -yv
        theta = self.correct(x.array_r, d)
        yv[:] = -d
        return theta > 0.0
