"""The contact terms of a set of pairs on one displacement field (:class:`Contact`).

:class:`Contact` holds the pairs' surfaces and states: it evaluates them at the current
displacement, adds their forces to a residual and their tangent to a Jacobian, runs the
augmented Lagrangian's Uzawa updates and answers the outputs. The work is done by the modules
beside it (points, evaluation, jacobian, output). MPI: slave facets are dealt evenly to the
ranks (:mod:`~.balance`), mesh masters are gathered on every rank; rows touched on other ranks
go through PETSc's stash (vectors) or an explicit all-to-all (matrices).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import dolfinx
import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from shoulder_fem.engine.contact import output
from shoulder_fem.engine.contact.balance import global_dofs, share_slaves
from shoulder_fem.engine.contact.curved import lift_surfaces
from shoulder_fem.engine.contact.evaluation import couplings, evaluate_pair, facet_projection
from shoulder_fem.engine.contact.geometry import P2_SUBTRIANGLES, segment_rule, slave_rule
from shoulder_fem.engine.contact.jacobian import add_to_pattern, jacobian_triplets, triplet_matrix
from shoulder_fem.engine.contact.masters import ContactError, MeshSurface
from shoulder_fem.engine.contact.pair import ContactPair
from shoulder_fem.engine.contact.points import fixed_points, segment_points
from shoulder_fem.engine.contact.surfaces import MasterMesh, gather_master, surface_facets


@dataclass
class ContactStats:
    """Work counters (wall seconds are this rank's)."""

    evaluations: int = 0
    search_s: float = 0.0
    assembly_s: float = 0.0
    pattern_merges: int = 0
    uzawa_iterations: int = 0
    active_changes: list[int] = field(default_factory=list)


def _check_options(slave_integration: str, mesh_integration: str) -> None:
    """Raise a :class:`ContactError` for an unknown integration option."""
    if slave_integration not in ("subtriangles", "element"):
        raise ContactError(
            f"slave_integration = {slave_integration!r}: expected 'subtriangles' or 'element'"
        )
    if mesh_integration not in ("segments", "points"):
        raise ContactError(
            f"mesh_integration = {mesh_integration!r}: expected 'segments' or 'points'"
        )


def _bc_rows(bcs, w_l2g: np.ndarray, bs: int, comm: MPI.Comm) -> np.ndarray:
    """Global rows of the Dirichlet conditions ``bcs`` on every rank (collective)."""
    rows = []
    for bc in bcs:
        idx, _ = bc.dof_indices()
        idx = np.asarray(idx, dtype=np.int64)
        rows.append(w_l2g[idx // bs] * bs + idx % bs if len(idx) else idx)
    local = np.concatenate(rows) if rows else np.zeros(0, dtype=np.int64)
    return np.unique(np.concatenate(comm.allgather(local)))


def _gathered_master(V, Q, facet_tags, pair: ContactPair, node_rows, X) -> MasterMesh | None:
    """``pair``'s mesh master gathered on every rank (collective); None for a rigid master."""
    if not isinstance(pair.master, MeshSurface):
        return None
    overlap = set(pair.master.tags) & set(pair.slave)
    if overlap:
        raise ContactError(
            f"contact pair {pair.name!r}: tags {sorted(overlap)} are both slave and master"
        )
    what = f"contact pair {pair.name!r}, master"
    mf = surface_facets(V, facet_tags, pair.master.tags, Q, what, X)
    return gather_master(V, mf, V.mesh.comm, node_rows, X)


def _slave_facets(V, Q, facet_tags, pairs: Sequence[ContactPair], X) -> list:
    """Every pair's slave facets on this rank, at the reference positions ``X`` (collective)."""
    what = "contact pair {!r}, slave"
    return [surface_facets(V, facet_tags, p.slave, Q, what.format(p.name), X) for p in pairs]


class Contact:
    """The contact terms of a set of pairs on one displacement field (collective methods).

    Contact points (:mod:`~.points`): against an analytic master, a fixed rule on every slave
    facet (``quadrature_degree``; 0 = at the nodes) with ``slave_integration`` ("subtriangles":
    a P2 facet as its 4 flat sub-triangles, "element": its own shape functions). Against a
    mesh master, with ``mesh_integration = "segments"`` (default), each slave facet (or P2
    sub-triangle) cut along the master triangles it overlaps, with a rule of degree 2 (P1) or 4
    (P2) on every piece (exact loads on both sides, the patch test); ``"points"``: the fixed
    rule with a closest-point search.

    Args:
        V: Vector P1/P2 space on a tetrahedral mesh, or the displacement block of a mixed
            space (``W.sub(0)`` of a Taylor-Hood space); rows and columns are then those of W.
        u: Displacement (m), or the mixed function on W; read at every evaluation.
        facet_tags: The mesh's facet tags.
        pairs: Contact pairs.
        bcs: Dirichlet conditions of the solve: their rows and columns get no contact terms.
        quadrature_degree: Degree of the fixed rule (0: the nodes).
        slave_integration: "subtriangles" or "element" (P2 slaves, fixed rule).
        mesh_integration: "segments" or "points" (mesh masters).
        share: Deal the slave facets evenly to the ranks (:mod:`~.balance`); ``False``: each
            is handled by the rank owning its cell.
    """

    def __init__(
        self,
        V: dolfinx.fem.FunctionSpace,
        u: dolfinx.fem.Function,
        facet_tags: dolfinx.mesh.MeshTags,
        pairs: Sequence[ContactPair],
        bcs: Sequence[dolfinx.fem.DirichletBCMetaClass] = (),
        quadrature_degree: int = 4,
        slave_integration: str = "subtriangles",
        mesh_integration: str = "segments",
        share: bool = True,
    ):
        self.u, self.pairs = u, list(pairs)
        self._penalties = [p.penalty for p in self.pairs]  # each pair's own (Pa/m)
        self.comm = V.mesh.comm
        W = u.function_space
        if V.component():  # the displacement block of a mixed space (e.g. Taylor-Hood)
            V, umap = V.collapse()
            self._umap = np.asarray(umap, dtype=np.int64)
        else:
            self._umap = np.arange(len(u.x.array), dtype=np.int64)
        self.V = V
        self._X = V.tabulate_dof_coordinates()  # reference node positions (never change)
        names = [p.name for p in self.pairs]
        if len(set(names)) != len(names):
            raise ContactError(f"contact pair names must be unique: {names}")
        self.stats = ContactStats()
        self.degree = V.ufl_element().degree()
        if V.dofmap.index_map_bs != 3:
            raise ContactError("contact needs a 3D vector displacement space (or its block)")
        self.Q = dolfinx.fem.FunctionSpace(V.mesh, ("CG", 1))
        _check_options(slave_integration, mesh_integration)
        self.mesh_integration = mesh_integration
        rule = slave_rule(self.degree, quadrature_degree, slave_integration == "subtriangles")
        self._pieces = np.array([(0, 1, 2)] if self.degree == 1 else P2_SUBTRIANGLES)
        # segments: linear x linear integrands for P1, quadratic x linear for P2
        self._seg_rule = segment_rule(2 if self.degree == 1 else 4)
        # global row of each displacement component of each node of V, in u's own space
        wmap, wbs = W.dofmap.index_map, W.dofmap.index_map_bs
        self._w_l2g = wmap.local_to_global(
            np.arange(wmap.size_local + wmap.num_ghosts, dtype=np.int32)
        )
        self._node_rows = (self._w_l2g[self._umap // wbs] * wbs + self._umap % wbs).reshape(-1, 3)
        self._bc_global = _bc_rows(bcs, self._w_l2g, wbs, self.comm)
        self._build_surfaces(facet_tags, rule, share)
        self._merged = np.zeros(0, dtype=np.int64)
        self._last_tangent: PETSc.Mat | None = None
        self._last_u = None
        self._x_prev = None
        self._x_nodes: np.ndarray | None = None  # node positions at the last evaluation
        self.commit()

    def _build_surfaces(self, facet_tags: dolfinx.mesh.MeshTags, rule, share: bool) -> None:
        """Slave facets (dealt to the ranks), their fixed points and multipliers; the masters.

        The slaves' nodes index this rank's nodes, then the imported ones (:mod:`~.balance`):
        ``_slave_rows`` are their global rows; their ``p1`` are global CG1 dofs.
        """
        self._state = [None] * len(self.pairs)
        #: the mid-edge nodes lifted onto curved surfaces (``ContactPair.curved``), all ranks
        self._X, self.lifted = lift_surfaces(self.V, self.Q, facet_tags, self.pairs, self._X)
        found = _slave_facets(self.V, self.Q, facet_tags, self.pairs, self._X)
        comm = self.comm if share else MPI.COMM_SELF  # COMM_SELF: every facet stays
        self._slaves, self._import = share_slaves(found, len(self._X), global_dofs(self.Q), comm)
        self._slave_rows = self._import.extend(self._node_rows)
        self._fixed = [fixed_points(sl, *rule) for sl in self._slaves]
        self._lam = [np.zeros((len(sl.nodes), 3)) for sl in self._slaves]
        self._masters = [
            _gathered_master(self.V, self.Q, facet_tags, pair, self._node_rows, self._X)
            for pair in self.pairs
        ]

    # -- helpers -----------------------------------------------------------------------------
    def _current(self) -> np.ndarray:
        """Current positions of this rank's nodes, then of its imported ones (collective)."""
        return self._import.extend(self._X + self.u.x.array[self._umap].reshape(-1, 3))

    def _update_masters(self, x_nodes: np.ndarray) -> None:
        for m in self._masters:
            if m is None:
                continue
            parts = self.comm.allgather(x_nodes[m.owned_nodes])
            m.x = np.concatenate(parts).reshape(-1, 3)

    def commit(self) -> None:
        """Make the current state the start of the next load step (friction slip reference)."""
        x_nodes = self._current()
        self._update_masters(x_nodes)
        self._x_prev = x_nodes.copy()
        for m in self._masters:
            if m is not None:
                m.x_prev = m.x.copy()

    # -- evaluation --------------------------------------------------------------------------
    def evaluate(self) -> None:
        """Search the pairing and compute pressures and tractions at the current ``u``."""
        t0 = time.perf_counter()
        x_nodes = self._x_nodes = self._current()  # kept for the tangent at this same u
        self._update_masters(x_nodes)
        changes = 0
        for i, pair in enumerate(self.pairs):
            old = self._state[i]
            sl, master = self._slaves[i], self._masters[i]
            if master is not None and self.mesh_integration == "segments":
                pts = segment_points(pair, sl, master, x_nodes, self._pieces, self._seg_rule)
            else:
                pts = self._fixed[i]
            st = evaluate_pair(pair, sl, master, pts, x_nodes, self._x_prev, self._lam[i])
            if old is not None:
                if len(old["active"]) == len(st["active"]):
                    changes += int(np.count_nonzero(old["active"] != st["active"]))
                else:
                    changes += abs(int(old["active"].sum()) - int(st["active"].sum()))
            self._state[i] = st
        self.stats.evaluations += 1
        self.stats.active_changes.append(self.comm.allreduce(changes, op=MPI.SUM))
        self.stats.search_s += time.perf_counter() - t0
        self._last_u = self.u.x.array.copy()

    def _ensure(self) -> None:
        """Evaluate if ``u`` changed on any rank (collective).

        A rank whose part of ``u`` did not change must still join the others' evaluation (its
        gathers), or they wait for it forever.
        """
        changed = self._last_u is None or not np.array_equal(self._last_u, self.u.x.array)
        if self.comm.allreduce(changed, op=MPI.LOR):
            self.evaluate()

    # -- residual and tangent ----------------------------------------------------------------
    def add_residual(self, b: PETSc.Vec) -> None:
        """Add the contact forces to a residual vector (F_int - F_ext convention; collective)."""
        self._ensure()
        t0 = time.perf_counter()
        rows, vals = [], []
        for st, sl, m in zip(self._state, self._slaves, self._masters, strict=True):
            act, node_rows, coef = couplings(st, sl, m, self._slave_rows)
            force = (st["p"][act, None] * st["n"][act] + st["t"][act]) * st["W"][act, None]
            r = -coef[:, :, None] * force[:, None, :]  # (nqa, k, 3)
            rows.append(node_rows.ravel())
            vals.append(r.ravel())
        rows = np.concatenate(rows) if rows else np.zeros(0, dtype=np.int64)
        vals = np.concatenate(vals) if vals else np.zeros(0)
        keep = ~np.isin(rows, self._bc_global)
        b.setValues(rows[keep].astype(PETSc.IntType), vals[keep], addv=PETSc.InsertMode.ADD_VALUES)
        b.assemblyBegin()
        b.assemblyEnd()
        self.stats.assembly_s += time.perf_counter() - t0

    def jacobian_matrix(self, A: PETSc.Mat, reuse: PETSc.Mat | None = None) -> PETSc.Mat:
        """The contact tangent, an AIJ matrix of A's layout: ``reuse`` (the last) if its pattern."""
        self._ensure()
        t0 = time.perf_counter()
        segments = None
        if self.mesh_integration == "segments":
            segments = dict(
                x_nodes=self._x_nodes, pieces=self._pieces, rule=self._seg_rule, lam=self._lam
            )
        state = (self.pairs, self._state, self._slaves, self._masters, self._slave_rows)
        rows, cols, vals = jacobian_triplets(*state, self._bc_global, segments)
        mine = reuse is not None and reuse is self._last_tangent
        last = (reuse, self._pattern_keys) if mine else None
        K, self._pattern_keys = triplet_matrix(A, rows, cols, vals, self.comm, last)
        self._last_tangent = K
        self.stats.assembly_s += time.perf_counter() - t0
        return K

    def add_jacobian(self, A: PETSc.Mat) -> None:
        """Add the contact tangent to an assembled FE Jacobian (collective)."""
        K = self.jacobian_matrix(A)
        t0 = time.perf_counter()
        n_before = len(self._merged)
        self._merged = add_to_pattern(A, K, self._merged, self.comm, self._pattern_keys)
        self.stats.pattern_merges += int(len(self._merged) != n_before)
        K.destroy()
        self.stats.assembly_s += time.perf_counter() - t0

    # -- augmented Lagrangian ----------------------------------------------------------------
    @property
    def augmented(self) -> bool:
        """Whether any pair uses the augmented Lagrangian."""
        return any(p.method == "augmented" for p in self.pairs)

    def max_penetration(self) -> float:
        """Largest penetration -g over the active points of all pairs (m; collective)."""
        self._ensure()
        local = 0.0
        for st in self._state:
            if np.any(st["active"]):
                local = max(local, float(np.max(-st["g"][st["active"]])))
        return self.comm.allreduce(local, op=MPI.MAX)

    def augment(self) -> bool:
        """Check the augmented pairs and make one Uzawa update lambda <- p where needed.

        A pair has converged when every point carrying pressure has |g| <= gap_tolerance (no
        penetration beyond it, and no pressure held across an open gap). Returns True when all
        augmented pairs have (their multipliers are then left as they are).
        """
        self._ensure()
        done = True
        for i, pair in enumerate(self.pairs):
            if pair.method != "augmented":
                continue
            st = self._state[i]
            act = st["active"]
            err = float(np.max(np.abs(st["g"][act]))) if np.any(act) else 0.0
            err = self.comm.allreduce(err, op=MPI.MAX)
            if err > pair.gap_tolerance:
                done = False
                self._lam[i] = facet_projection(st, len(self._slaves[i].nodes), st["p"])
        self.stats.uzawa_iterations += 1
        self._last_u = None
        return done

    def reset_multipliers(self) -> None:
        """Forget the augmented Lagrangian multipliers."""
        for lam in self._lam:
            lam[:] = 0.0
        self._last_u = None

    def multipliers(self) -> list[np.ndarray]:
        """Copies of the multipliers (for a cut-back's snapshot)."""
        return [lam.copy() for lam in self._lam]

    def set_multipliers(self, values: list[np.ndarray]) -> None:
        """Restore multipliers taken by :meth:`multipliers`."""
        self._lam = [v.copy() for v in values]
        self._last_u = None

    # -- outputs -----------------------------------------------------------------------------
    def resultants(self, point: Sequence[float] = (0.0, 0.0, 0.0), by_tag: bool = False) -> dict:
        """Resultants of every pair (per slave tag if ``by_tag``; :func:`.output.resultants`)."""
        self._ensure()
        slaves = self._slaves if by_tag else None
        return output.resultants(self.pairs, self._state, self.comm, point, slaves)

    def master_points(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """Where pair ``name`` presses on its mesh master, in the master's reference geometry.

        Returns this rank's active contact points as their closest master points in the
        reference configuration (m, (n, 3): the master nodes' reference positions weighted as
        the current closest points) and their normal forces p dA (N, (n,)). Collective (it
        may evaluate the contact).

        Raises:
            ContactError: No pair of that name, or its master is not a mesh surface.
        """
        names = [p.name for p in self.pairs]
        if name not in names:
            raise ContactError(f"no contact pair {name!r} (pairs: {', '.join(names)})")
        i = names.index(name)
        if self._masters[i] is None:
            raise ContactError(f"contact pair {name!r}: its master is not a mesh surface")
        self._ensure()
        return output.master_points(self._state[i], self._masters[i])

    def scale_penalties(self, factor: float) -> None:
        """Every pair's penalty at ``factor`` x its own (a continuation; 1 gives them back)."""
        own = zip(self.pairs, self._penalties, strict=True)
        self.pairs = [replace(p, penalty=e * factor) for p, e in own]
        self._last_u = None

    def point_state(self, index: int) -> dict:
        """Pair ``index``'s points at the last evaluation: ``xq`` (m), ``p`` (Pa), ``active``."""
        return self._state[index]

    def pressure_fields(self) -> tuple[dolfinx.fem.Function, dolfinx.fem.Function]:
        """Nodal contact pressure and shear (Pa) on the slave and mesh-master surfaces (CG1).

        A lumped projection of the contact points' values with the facets' linear functions.
        """
        self._ensure()
        return output.pressure_fields(self.Q, self._slaves, self._state, self._masters)


def record_resultants(
    contact: Contact, recorder, prefix: str = "", point: Sequence[float] = (0.0, 0.0, 0.0)
) -> None:
    """Put every pair's resultants in a run's probes as ``<prefix><pair>_<name>`` (SI)."""
    for pair, res in contact.resultants(point).items():
        for key, unit in output.RESULTANT_UNITS.items():
            recorder.set_probe(f"{prefix}{pair}_{key}", res[key], unit)
