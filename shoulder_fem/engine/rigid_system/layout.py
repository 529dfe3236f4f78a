"""Where every unknown of a :class:`RigidSystem` lives, and the prolongation P to the FE DOFs.

Which FE nodes are free, tied to a body or fixed, the reduced numbering (free FE DOFs, then six
per body), P and the spring ends resolved to DOFs: built once per system, apart from the SNES
driver that uses them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import dolfinx
import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from shoulder_fem.engine.fem import owned_flags
from shoulder_fem.engine.rigid_system.bodies import RigidBody, Tie
from shoulder_fem.engine.rigid_system.terms import SpringEnd, left_jacobian
from shoulder_fem.engine.so3 import hats
from shoulder_fem.engine.springs import GROUND, Spring

__all__ = ["ReducedLayout", "check_topology"]


def check_topology(
    bodies: Sequence[RigidBody],
    springs: Sequence[Spring],
    ties: Sequence[Tie],
    surfaces: Mapping[str, tuple[dolfinx.mesh.MeshTags, int]],
    fixed: Sequence[str],
    deformable: str | None,
    dynamic: bool,
    comm: MPI.Comm,
) -> None:
    """Check the names and the holding of a system's parts before anything is built (collective).

    Raises:
        ValueError: Duplicate body names, a tie to an unknown body or surface, an empty
            surface, a spring on an unknown body, or a free rigid body that nothing holds
            (static scene, or massless in a dynamic one).
    """
    names = [b.name for b in bodies]
    if len(set(names)) != len(names) or GROUND in names:
        raise ValueError(f"rigid body names must be unique and not '{GROUND}': {names}")
    for surface in list(fixed) + [t.surface for t in ties]:
        if surface not in surfaces:
            raise ValueError(
                f"surface '{surface}' does not exist (known: {', '.join(surfaces) or 'none'})"
            )
        tags, tag = surfaces[surface]
        count = comm.allreduce(len(tags.find(tag)), op=MPI.SUM)
        if count == 0:
            raise ValueError(f"surface '{surface}' (tag {tag}) has no facets")
    for tie in ties:
        if tie.body not in names:
            raise ValueError(
                f"tie of surface '{tie.surface}': unknown rigid body '{tie.body}' "
                f"(known: {', '.join(names) or 'none'})"
            )
    known = names + [GROUND] + ([deformable] if deformable else [])
    for s in springs:
        for end in (s.body_a, s.body_b):
            if end not in known:
                raise ValueError(
                    f"spring '{s.name}': unknown body '{end}' (known: {', '.join(known)})"
                )
    held = {t.body for t in ties}
    held |= {s.body_a for s in springs} | {s.body_b for s in springs}
    for b in bodies:
        if dynamic and b.mass is not None:
            continue
        if not b.prescribed and b.name not in held:
            why = (
                "and has no mass: a dynamic scene cannot integrate it"
                if dynamic
                else "a static scene cannot balance its loads"
            )
            raise ValueError(
                f"rigid body '{b.name}' is held by nothing (no tie, no spring, not "
                f"prescribed): {why}"
            )


class ReducedLayout:
    """The reduced unknowns of a system and the prolongation P that maps them to FE DOFs.

    The reduced unknown vector holds every free displacement DOF of the deformable body (not
    tied, not fixed) and six DOFs per rigid body: the translation ``t`` of its reference point
    (m) and an incremental rotation vector ``φ`` (rad) measured from the body's rotation ``R₀``
    at the start of the current solve, ``R = exp(hat φ) R₀``. The rigid DOFs are owned by
    **rank 0** (the last entries of its local block); every rank builds the same layout.

    A node of a tied surface with reference position X follows its body exactly,
    ``x = X_ref + t + R (X - X_ref)``, so its displacement is a function of the six DOFs and
    distances between tied nodes are preserved to round-off at any rotation. ``P`` (PETSc
    MPIAIJ, rows = all FE DOFs, columns = reduced DOFs) maps a reduced correction to a
    displacement correction: identity on free DOFs, zero rows on fixed DOFs and on a tied node
    i, with ``r_i = R (X_i - X_ref)``,

        δu_i = δt + δθ × r_i = δt - hat(r_i) J_l(φ) δφ,

    where δθ is the spatial rotation increment and ``J_l(φ) = J_r(-φ)`` the left Jacobian.

    Args:
        comm: Communicator of the system.
        bodies: The rigid bodies (their number and names).
        ties: Which surface follows which body.
        V: The displacement's function space (3D vector Lagrange); ``None`` for rigid bodies
            and springs only.
        surfaces: Named surfaces ``{name: (MeshTags, tag id)}``.
        fixed: Names of surfaces whose nodes are fixed.

    Raises:
        ValueError: ``V`` is not a 3D vector space, or a node both tied and fixed or tied twice.
    """

    def __init__(
        self,
        comm: MPI.Comm,
        bodies: Sequence[RigidBody],
        ties: Sequence[Tie],
        V: dolfinx.fem.FunctionSpace | None = None,
        surfaces: Mapping[str, tuple[dolfinx.mesh.MeshTags, int]] | None = None,
        fixed: Sequence[str] = (),
    ) -> None:
        self.comm = comm
        self.fe = V is not None
        #: Per body, the local (owned + ghost) and the owned node indices tied to it.
        self.tied_nodes: list[np.ndarray] = []
        self.tied_owned: list[np.ndarray] = []
        #: Per fixed surface, its owned node indices.
        self.fixed_owned: dict[str, np.ndarray] = {}
        #: Reference coordinates of the local nodes (m), (n_all, 3); ``None`` without FE.
        self.X: np.ndarray | None = None
        #: The body points the local nodes are tied at (m), (n_all, 3): ``X`` plus each tied
        #: node's offset in its body's frame (:meth:`set_offsets`); ``X`` itself while no node
        #: has one.
        self.X_tied: np.ndarray | None = None
        self.n_owned = 0
        self.free_nodes = np.zeros(0, dtype=np.int64)
        n_free_local = 0
        if V is not None:
            self._classify_nodes(V, dict(surfaces or {}), bodies, ties, fixed)
            n_free_local = 3 * len(self.free_nodes)
        nb = len(bodies)
        self.n_free_local = n_free_local
        n_local = n_free_local + (6 * nb if comm.rank == 0 else 0)
        self.n_local = n_local
        self.start = comm.exscan(n_local) or 0
        self.rigid_start = comm.bcast(self.start + n_free_local, root=0)
        self.n_global = comm.allreduce(n_local, op=MPI.SUM)

    def _classify_nodes(
        self,
        V: dolfinx.fem.FunctionSpace,
        surfaces: Mapping[str, tuple[dolfinx.mesh.MeshTags, int]],
        bodies: Sequence[RigidBody],
        ties: Sequence[Tie],
        fixed: Sequence[str],
    ) -> None:
        """Owned nodes free / tied / fixed (collective)."""
        comm = self.comm
        imap = V.dofmap.index_map
        if V.dofmap.index_map_bs != 3:
            raise ValueError("RigidSystem: u must be a 3D vector function")
        self.n_owned = imap.size_local
        n_all = self.n_owned + imap.num_ghosts
        self.X = V.tabulate_dof_coordinates()[:n_all]
        self.X_tied = self.X

        def nodes_of(surface: str) -> np.ndarray:
            tags, tag = surfaces[surface]
            dofs = dolfinx.fem.locate_dofs_topological(V, tags.dim, tags.find(tag))
            return owned_flags(imap, dofs, comm)

        taken = np.zeros(n_all, dtype=bool)
        fixed_all = np.zeros(n_all, dtype=bool)
        for surface in fixed:
            flags = nodes_of(surface)
            self.fixed_owned[surface] = np.flatnonzero(flags[: self.n_owned])
            fixed_all |= flags
        #: Per local node, the index of the body it is tied to, or -1.
        self.tie_flags = np.full(n_all, -1, dtype=np.int64)
        for b in range(len(bodies)):
            flags = np.zeros(n_all, dtype=bool)
            for tie in ties:
                if tie.body == bodies[b].name:
                    flags |= nodes_of(tie.surface)
            both = comm.allreduce(int(np.count_nonzero(flags & fixed_all)), op=MPI.SUM)
            twice = comm.allreduce(int(np.count_nonzero(flags & taken)), op=MPI.SUM)
            if both or twice:
                raise ValueError(
                    f"rigid body '{bodies[b].name}': {both} tied node(s) also fixed, "
                    f"{twice} tied to another body"
                )
            taken |= flags
            self.tie_flags[flags] = b
            self.tied_nodes.append(np.flatnonzero(flags))
            self.tied_owned.append(np.flatnonzero(flags[: self.n_owned]))
        #: Per local node, whether it is fixed.
        self.fixed_all = fixed_all
        free = ~(taken | fixed_all)[: self.n_owned]
        self.free_nodes = np.flatnonzero(free)
        #: First global FE row of this rank and the number of FE rows (3 per node).
        self.row0 = imap.local_range[0] * 3
        self.n_rows_global = imap.size_global * 3

    def set_offsets(self, b: int, offsets: np.ndarray | None) -> None:
        """Tie body ``b``'s local nodes (``tied_nodes[b]``) at ``X + offsets`` (m, (n, 3)).

        ``None``: at ``X`` again.
        """
        nodes = self.tied_nodes[b]
        if self.X_tied is self.X:
            self.X_tied = self.X.copy()
        self.X_tied[nodes] = self.X[nodes] + (0.0 if offsets is None else offsets)

    def rigid_cols(self, b: int) -> np.ndarray:
        """Global reduced indices of body ``b``'s six DOFs (t, φ)."""
        return self.rigid_start + 6 * b + np.arange(6, dtype=PETSc.IntType)

    def rigid_range(self, nb: int) -> np.ndarray:
        """Global reduced indices of the rigid DOFs of all ``nb`` bodies."""
        return np.arange(self.rigid_start, self.rigid_start + 6 * nb, dtype=PETSc.IntType)

    def rigid_modes(self, bodies: Sequence[RigidBody], template: PETSc.Vec) -> list[PETSc.Vec]:
        """The six infinitesimal rigid motions of the whole system as reduced vectors.

        A motion t0 + ω x x (reference positions, about the free nodes' centroid) moves a free
        node by t0 + ω x X and a body by t = t0 + ω x X_ref, φ = ω (small rotations): the
        near-nullspace of an iterative solver. Not orthonormalised (collective).
        """
        comm = self.comm
        X = self.X[self.free_nodes] if self.fe else np.zeros((0, 3))
        total = comm.allreduce(len(X), op=MPI.SUM)
        centre = comm.allreduce(X.sum(axis=0), op=MPI.SUM) / max(total, 1)
        modes = []
        for k in range(6):
            e = np.eye(3)[k % 3]
            v = template.duplicate()
            arr = v.array  # a view of the owned values
            if k < 3:
                arr[: self.n_free_local] = np.tile(e, len(X))
            else:
                arr[: self.n_free_local] = np.cross(e, X - centre).ravel()
            if comm.rank == 0:
                for b, body in enumerate(bodies):
                    i = self.n_free_local + 6 * b
                    if k < 3:
                        arr[i : i + 3] = e
                    else:
                        arr[i : i + 3] = np.cross(e, body.reference_point - centre)
                        arr[i + 3 : i + 6] = e
            v.assemble()
            modes.append(v)
        return modes

    def create_prolongation(
        self, bodies: Sequence[RigidBody], phi: np.ndarray, linear_ties: bool
    ) -> PETSc.Mat:
        """A new P, filled at the bodies' current rotations (collective)."""
        comm = self.comm
        n_rows = 3 * self.n_owned
        d_nnz = np.zeros(n_rows, dtype=PETSc.IntType)
        o_nnz = np.zeros(n_rows, dtype=PETSc.IntType)
        free_rows = (3 * self.free_nodes[:, None] + np.arange(3)).ravel()
        d_nnz[free_rows] = 1
        for owned in self.tied_owned:
            rows = (3 * owned[:, None] + np.arange(3)).ravel()
            (d_nnz if comm.rank == 0 else o_nnz)[rows] = 6
        P = PETSc.Mat().createAIJ(
            ((n_rows, self.n_rows_global), (self.n_local, self.n_global)), comm=comm
        )
        P.setPreallocationNNZ((d_nnz, o_nnz))
        P.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, True)
        for k, row in enumerate(free_rows):
            P.setValue(self.row0 + row, self.start + k, 1.0)
        self.fill_prolongation(P, bodies, phi, linear_ties)
        return P

    def fill_prolongation(
        self, P: PETSc.Mat, bodies: Sequence[RigidBody], phi: np.ndarray, linear_ties: bool
    ) -> None:
        """Tied rows of P at the current rotations: [I, -hat(r_i) J_l(φ)] (collective).

        ``linear_ties``: small-rotation ties, [I, -hat(X_i - X_ref)].
        """
        for b, owned in enumerate(self.tied_owned):
            if len(owned) == 0:
                continue
            cols = self.rigid_cols(b)
            body = bodies[b]
            if linear_ties:
                jl, r = np.eye(3), self.X[owned] - body.reference_point
            else:
                jl = left_jacobian(phi[b])
                r = (self.X_tied[owned] - body.reference_point) @ body.rotation.T
            # every tied row has the body's 6 columns: one dense (3 n) x 6 block, one call
            block = np.empty((len(owned), 3, 6))
            block[:, :, :3] = np.eye(3)
            block[:, :, 3:] = -hats(r) @ jl
            rows = (self.row0 + 3 * np.asarray(owned)[:, None] + np.arange(3)).ravel()
            P.setValues(rows.astype(PETSc.IntType), cols, block.reshape(-1, 6))
        P.assemble()

    def spring_end(
        self, spring: Spring, which: int, index: Mapping[str, int], deformable: str | None
    ) -> SpringEnd:
        """End ``which`` (0: a, 1: b) of ``spring`` resolved to the layout (collective).

        ``index`` maps body names to indices; an end on ``deformable`` is attached to the FE
        node at its point: a free node, or a tied node (then a rigid end) or a fixed one (then
        a ground end).

        Raises:
            ValueError: An end on the deformable body whose point is not a node.
        """
        body = (spring.body_a, spring.body_b)[which]
        point = np.asarray((spring.point_a, spring.point_b)[which], dtype=float)
        if body == GROUND:
            return SpringEnd("ground", -1, point, -1, -1, -1)
        if body != deformable:
            return SpringEnd("rigid", index[body], point, -1, -1, -1)
        comm = self.comm
        own = self.X[: self.n_owned]
        dist = np.linalg.norm(own - point, axis=1) if len(own) else np.array([np.inf])
        k = int(np.argmin(dist))
        best, owner = comm.allreduce((float(dist[k]), comm.rank), op=MPI.MINLOC)
        extent = comm.allreduce(float(np.ptp(own, axis=0).max()) if len(own) else 0.0, op=MPI.MAX)
        if best > 1e-8 * extent:
            raise ValueError(
                f"spring '{spring.name}': point {point.tolist()} m is not a node of the "
                f"deformable body '{body}' (nearest at {best:.3g} m)"
            )
        info = None
        if comm.rank == owner:
            X = self.X[k].copy()
            if self.fixed_all[k]:
                info = SpringEnd("ground", -1, X, -1, -1, -1)
            elif self.tie_flags[k] >= 0:
                info = SpringEnd("rigid", int(self.tie_flags[k]), X, -1, -1, -1)
            else:
                pos = int(np.searchsorted(self.free_nodes, k))
                info = SpringEnd("node", -1, X, owner, k, self.start + 3 * pos)
        return comm.bcast(info, root=owner)

    def end_dofs(self, end: SpringEnd, T: np.ndarray) -> tuple[np.ndarray, int, np.ndarray | None]:
        """Reduced indices of a spring end, their owner rank, and a rigid end's (t, φ) map.

        The map is the end body's (6, 6) block of ``T`` = diag(I, J_l(φ)); None for a node end.
        """
        kind, b, _, owner, _, col0 = end
        if kind == "node":
            return col0 + np.arange(3, dtype=PETSc.IntType), owner, None
        return self.rigid_cols(b), 0, T[6 * b : 6 * b + 6, 6 * b : 6 * b + 6]

    def prescribed_rows(self, bodies: Sequence[RigidBody]) -> np.ndarray:
        """Global reduced indices of the prescribed bodies' DOFs (on rank 0; empty elsewhere)."""
        rows = [self.rigid_cols(b) for b, body in enumerate(bodies) if body.prescribed]
        if self.comm.rank != 0 or not rows:
            return np.zeros(0, dtype=PETSc.IntType)
        return np.concatenate(rows)

    def add_node_blocks(
        self, J: PETSc.Mat, ends: Sequence[SpringEnd], node_tangent: list, T: np.ndarray
    ) -> None:
        """Add the spring tangent blocks touching free FE nodes (set by the rows' owner).

        ``node_tangent`` holds ``(row end, col end, block)`` (:func:`terms.spring_terms`), a
        rigid side in (t, θ), mapped here to (t, φ) by ``T`` = diag(I, J_l(φ)).
        """
        for i, k, block in node_tangent:
            rows, owner, Ti = self.end_dofs(ends[i], T)
            cols, _, Tk = self.end_dofs(ends[k], T)
            if self.comm.rank != owner:
                continue
            if Ti is not None:
                block = Ti.T @ block
            if Tk is not None:
                block = block @ Tk
            J.setValues(rows, cols, block.ravel(), addv=PETSc.InsertMode.ADD_VALUES)
