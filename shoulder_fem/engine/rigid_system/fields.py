"""A system's unknowns as the fields of a block preconditioner (a mixin of RigidSystem).

:class:`~shoulder_fem.engine.block_split.StiffSoftSplit` needs each rank's owned rows of the
reduced layout sorted into a stiff field, a soft field and a border; :class:`SplitFields` sorts
them from FE nodes and body names.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from petsc4py import PETSc

from shoulder_fem.engine.rigid_system.layout import ReducedLayout

__all__ = ["SplitFields", "reduced_rows"]


def reduced_rows(
    layout: ReducedLayout, nodes: np.ndarray, bodies: Sequence[int] = ()
) -> np.ndarray:
    """This rank's owned reduced rows of the free ones of the local ``nodes`` and ``bodies``.

    Three rows per free node (in the layout's order); on rank 0, each body's six.
    """
    at = np.flatnonzero(np.isin(layout.free_nodes, np.asarray(nodes)))
    rows = [layout.start + (3 * at[:, None] + np.arange(3)).ravel()]
    if layout.comm.rank == 0:
        rows += [layout.rigid_cols(b) for b in bodies]
    return np.concatenate(rows).astype(PETSc.IntType)


class SplitFields:
    """The field-split method of :class:`~.system.RigidSystem` (a mixin; collective)."""

    def split_fields(self, stiff_nodes: np.ndarray, stiff_bodies: Sequence[str]) -> None:
        """Give the SNES's :class:`~shoulder_fem.engine.block_split.StiffSoftSplit` its fields.

        The stiff field: the free ones of the local ``stiff_nodes`` (owned and ghost indices)
        and the ``stiff_bodies``; the border: the other bodies' DOFs; the soft field: every
        other free node.

        Raises:
            ValueError: The SNES's preconditioner is not a StiffSoftSplit (its options).
        """
        from shoulder_fem.engine.block_split import StiffSoftSplit

        pc = self.snes.getKSP().getPC()
        split = pc.getPythonContext() if pc.getType() == "python" else None
        if not isinstance(split, StiffSoftSplit):
            raise ValueError(
                f"{self.prefix}: split_fields needs pc_type python with "
                f"pc_python_type StiffSoftSplit (the preconditioner is '{pc.getType()}')"
            )
        layout = self._problem.layout
        stiff_b = [self._index[name] for name in stiff_bodies]
        border_b = [b for b in range(len(self.bodies)) if b not in stiff_b]
        stiff = reduced_rows(layout, stiff_nodes, stiff_b)
        border = reduced_rows(layout, np.zeros(0, np.int64), border_b)
        lo, hi = self._problem.x.getOwnershipRange()
        soft = np.setdiff1d(np.arange(lo, hi), np.concatenate([stiff, border]))
        split.set_fields(stiff, soft, border, self._problem.J)
