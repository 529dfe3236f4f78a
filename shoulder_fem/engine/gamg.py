"""Smoothed-aggregation AMG (GAMG) for elastic bodies held by rigid plates: a PETSc python PC.

:class:`ScaledGAMG` runs one GAMG V-cycle on the symmetrically scaled operator
D^-1/2 A D^-1/2 (D = diag A), with the operator's near-nullspace scaled to match (D^1/2 v).

Why the scaling: a :class:`~shoulder_fem.engine.rigid_system.RigidSystem` condenses every node
of a tied patch into its plate's six DOFs, whose rows sum the stiffness of the whole patch
(and whose rotation rows are in N m/rad). GAMG builds its tentative prolongator from the
near-nullspace restricted to each aggregate, so rows of so different scales in one aggregate
spoil it. Measured on the shoulder's part 2 at ``paper`` (29 082 unknowns, 21 plates, CG to
rtol 1e-10): plain GAMG with the rigid modes 366-450 iterations, with one slow Lanczos mode
per plate; on the scaled operator 94, as for the scapula with its patches clamped (92);
deflating the 6 global modes or the plates' unit vectors did not help (376-394).
"""

from __future__ import annotations

import dolfinx
from petsc4py import PETSc

__all__ = ["GAMG_DEFAULTS", "PYTHON_TYPE", "ScaledGAMG", "scaled_gamg_options"]

#: The ``pc_python_type`` that selects :class:`ScaledGAMG`.
PYTHON_TYPE = "shoulder_fem.engine.gamg.ScaledGAMG"
#: The inner GAMG's options (under the outer prefix + ``scaled_``). The threshold was measured
#: on part 2 (coarse / medium / paper iterations: 0.02: 147/134/108, 0.05: 125/120/94,
#: 0.08: 119/101/127).
GAMG_DEFAULTS = {
    "scaled_ksp_type": "preonly",
    "scaled_pc_type": "gamg",
    "scaled_pc_gamg_type": "agg",
    "scaled_pc_gamg_threshold": 0.05,
    "scaled_pc_gamg_coarse_eq_limit": 1000,
}


def scaled_gamg_options(rtol: float = 1e-8, max_it: int = 1000) -> dict:
    """CG preconditioned by :class:`ScaledGAMG` (the operator must be symmetric)."""
    return {
        "ksp_type": "cg",
        "ksp_rtol": rtol,
        "ksp_atol": 0.0,
        "ksp_max_it": max_it,
        "pc_type": "python",
        "pc_python_type": PYTHON_TYPE,
        **GAMG_DEFAULTS,
    }


class ScaledGAMG:
    """GAMG on D^-1/2 A D^-1/2; the near-nullspace is the preconditioning matrix's own.

    The inner solver has the outer options prefix + ``scaled_`` (``--petsc
    scaled_pc_gamg_threshold=0.08`` reaches it). The preconditioning matrix must have a
    positive diagonal and, for 3 DOFs per aggregation node, local sizes divisible by 3.
    """

    def __init__(self) -> None:
        self.ksp: PETSc.KSP | None = None
        self.As: PETSc.Mat | None = None
        self.s: PETSc.Vec | None = None
        self.work: PETSc.Vec | None = None

    def _inner(self, pc: PETSc.PC) -> PETSc.KSP:
        if self.ksp is None:
            self.ksp = PETSc.KSP().create(pc.getComm())
            self.ksp.setOptionsPrefix((pc.getOptionsPrefix() or "") + "scaled_")
            self.ksp.setType("preonly")
            self.ksp.getPC().setType("gamg")
        return self.ksp

    def setFromOptions(self, pc: PETSc.PC) -> None:  # noqa: N802 (petsc4py's hook name)
        """Let the inner GAMG read its options (prefix + ``scaled_``)."""
        self._inner(pc).setFromOptions()

    def setUp(self, pc: PETSc.PC) -> None:  # noqa: N802
        """Scale the preconditioning matrix and its near-nullspace; set GAMG up on them."""
        _, P = pc.getOperators()
        d = P.getDiagonal()
        low = d.min()[1]
        if not low > 0.0:
            raise ValueError(f"ScaledGAMG: the matrix's diagonal must be positive (min {low:.3g})")
        for obj in (self.As, self.s, self.work):
            if obj is not None:
                obj.destroy()
        ai, aj, av = P.getValuesCSR()
        (n_local, _), _ = P.getSizes()
        bs = 3 if P.getComm().tompi4py().allreduce(n_local % 3) == 0 else 1  # 3 on every rank
        self.As = PETSc.Mat().createAIJ(P.getSizes(), bsize=bs, csr=(ai, aj, av), comm=P.getComm())
        root = d  # D^1/2 from here on
        root.sqrtabs()
        self.s = root.copy()
        self.s.reciprocal()
        self.As.diagonalScale(self.s, self.s)
        near = P.getNearNullSpace()
        if near.handle and near.getVecs():  # petsc4py: a handle of 0 when there is none
            vecs = []
            for v in near.getVecs():
                w = v.copy()
                w.pointwiseMult(w, root)
                vecs.append(w)
            dolfinx.la.orthonormalize(vecs)
            self.As.setNearNullSpace(PETSc.NullSpace().create(vectors=vecs))
        root.destroy()
        self.work = self.s.duplicate()
        inner = self._inner(pc)
        inner.setOperators(self.As)
        inner.setUp()

    def apply(self, pc: PETSc.PC, x: PETSc.Vec, y: PETSc.Vec) -> None:
        """Y = D^-1/2 GAMG(D^-1/2 x)."""
        self.work.pointwiseMult(x, self.s)
        self.ksp.solve(self.work, y)
        y.pointwiseMult(y, self.s)

    def view(self, pc: PETSc.PC, viewer: PETSc.Viewer) -> None:
        """What ``-ksp_view`` prints: this PC and the inner GAMG."""
        viewer.printfASCII("  ScaledGAMG: GAMG on D^-1/2 A D^-1/2 (near-nullspace scaled)\n")
        if self.ksp is not None:
            self.ksp.view(viewer)

    def destroy(self, pc: PETSc.PC) -> None:
        """Free the inner solver, the scaled matrix and the work vectors."""
        for obj in (self.ksp, self.As, self.s, self.work):
            if obj is not None:
                obj.destroy()
        self.ksp = self.As = self.s = self.work = None
