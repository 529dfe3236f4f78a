"""The quarter ball (and block) driven by its approach until the contact force is F."""

from __future__ import annotations

import logging
import math

import dolfinx
import dolfinx.fem.petsc as fem_petsc
import numpy as np
import ufl
from mpi4py import MPI
from petsc4py import PETSc

from shoulder_fem.engine.contact import Contact, ContactPair
from shoulder_fem.engine.solver import ConvergenceError, NonlinearSolver
from shoulder_fem.families.hertz.model import (
    SYMMETRY_FACTOR,
    HertzModel,
    internal_power,
    vector_space,
)

logger = logging.getLogger(__name__)

#: Secant iterations allowed to match the contact force at one load step.
MAX_FORCE_ITERATIONS = 20
#: Uzawa iterations allowed per solve (augmented Lagrangian).
MAX_UZAWA = 30
#: Deformable flat, first solve from the unloaded state: a sub-step at this fraction of the
#: approach first. (The rigid predictor's initial penetration, the whole approach, sends Newton
#: astray against a mesh master with a stiff penalty: measured at the coarse level with the
#: factor 100, 30 iterations without converging at the approach of F/2, and 10 + 15 iterations
#: with the sub-step.)
COLD_START_FRACTION = 0.2


class HertzProblem:
    """The quarter ball (and block) with its contact, driven by the approach δ (collective)."""

    def __init__(self, model: HertzModel, options: dict | None = None):
        from shoulder_fem.meshes.contact_bodies import CONTACT

        self.model = model
        V = self.V = vector_space(model)
        u = self.u = dolfinx.fem.Function(V, name="displacement")
        q = {"quadrature_degree": 2 * (model.degree - 1)}
        dx = ufl.Measure("dx", domain=model.mesh, subdomain_data=model.cell_tags, metadata=q)
        self.internal = internal_power(model, u, ufl.TestFunction(V), dx)
        self._internal_form = dolfinx.fem.form(self.internal, form_compiler_params=q)
        bcs = self.bcs = self._boundary_conditions()
        pair = ContactPair(
            "ball",
            (CONTACT.id,),
            model.master(),
            penalty=model.penalty,
            method=model.contact_method,
            gap_tolerance=model.gap_tolerance,
        )
        self.contact = Contact(V, u, model.facet_tags, [pair], bcs=bcs, quadrature_degree=0)
        force_scale = model.force / SYMMETRY_FACTOR
        self.solver = NonlinearSolver(
            self.internal,
            u,
            bcs,
            name="hertz",
            options={
                "snes_atol": 1e-9 * force_scale,
                "snes_rtol": 1e-9,
                "snes_divergence_tolerance": -1.0,
                # mesh master: the active set settles over more iterations (measured: up to 17)
                **({"snes_max_it": 50} if model.deformable else {}),
                **(options or {}),
            },
            form_compiler_params=q,
            contact=self.contact,
        )
        self.delta = 0.0
        #: the solution before the last one: (approach, displacement array)
        self._previous = (0.0, np.zeros_like(u.x.array))
        self.newton: list[int] = []
        self.uzawa: list[int] = []

    def _boundary_conditions(self) -> list:
        """Symmetry planes, the driven top face and, on a deformable flat, the block's bottom."""
        from shoulder_fem.meshes.contact_bodies import (
            BALL,
            BLOCK_BOTTOM,
            BLOCK_SYM_X,
            BLOCK_SYM_Y,
            SYM_X,
            SYM_Y,
            TOP,
        )

        model, V = self.model, self.V
        mesh = model.mesh
        fdim = mesh.topology.dim - 1
        ft = model.facet_tags
        bcs = []
        sym = ((0, SYM_X, BLOCK_SYM_X), (1, SYM_Y, BLOCK_SYM_Y))
        for comp, *markers in sym:
            facets = np.unique(np.concatenate([ft.find(m.id) for m in markers]))
            Vi, _ = V.sub(comp).collapse()
            dofs_i = dolfinx.fem.locate_dofs_topological((V.sub(comp), Vi), fdim, facets)
            zero = dolfinx.fem.Function(Vi)
            bcs.append(dolfinx.fem.dirichletbc(zero, dofs_i, V.sub(comp)))
        top = dolfinx.fem.locate_dofs_topological(V.sub(2), fdim, ft.find(TOP.id))
        self._top_dofs = top
        self.minus_approach = dolfinx.fem.Constant(mesh, PETSc.ScalarType(0.0))
        bcs.append(dolfinx.fem.dirichletbc(self.minus_approach, top, V.sub(2)))
        self._bottom_dofs = None
        if model.deformable:  # the block's bottom fixed in z
            bottom = dolfinx.fem.locate_dofs_topological(V.sub(2), fdim, ft.find(BLOCK_BOTTOM.id))
            self._bottom_dofs = bottom
            zero = PETSc.ScalarType(0.0)
            bcs.append(dolfinx.fem.dirichletbc(zero, bottom, V.sub(2)))
            # the ball's nodes (blocked indices): the rigid predictor moves them only
            self._ball_nodes = dolfinx.fem.locate_dofs_topological(
                V, mesh.topology.dim, model.cell_tags.find(BALL.id)
            )
        else:
            self._ball_nodes = slice(None)
        return bcs

    def solve(self, delta: float, step: str, cold_start: bool = True) -> float:
        """Drive the top face down by ``delta`` (m); return the total contact force (N).

        Predictor: the ball moved rigidly by the change of approach. With a deformable flat
        (where the rigid move would push the whole increment into the block), the displacement
        interpolated linearly in the approach between the last two solutions (the unloaded state
        counting as one), after, from the unloaded state, a sub-step at
        :data:`COLD_START_FRACTION` of the approach.
        """
        if cold_start and self.model.deformable and self.delta <= 0 < delta:
            self.solve(COLD_START_FRACTION * delta, f"{step} (cold-start sub-step)", False)
        current = (self.delta, self.u.x.array.copy())
        (d0, u0), d1 = self._previous, self.delta
        if self.model.deformable and delta > 0 and d1 > 0 and d1 != d0:
            self.u.x.array[:] += (delta - d1) / (d1 - d0) * (self.u.x.array - u0)
        else:
            self.u.x.array.reshape(-1, 3)[self._ball_nodes, 2] -= delta - d1  # rigid
        self.u.x.scatter_forward()
        self.minus_approach.value = -delta
        self.delta = delta
        for k in range(MAX_UZAWA):
            self.newton.append(self.solver.solve(step=f"{step}, approach {delta:.6g} m"))
            if not self.contact.augmented or self.contact.augment():
                self.uzawa.append(k + 1)
                break
        else:
            raise ConvergenceError(
                f"{step}: penetration above gap_tolerance after {MAX_UZAWA} Uzawa iterations",
                "DIVERGED_UZAWA",
                MAX_UZAWA,
                self.solver.prefix,
            )
        self._previous = current
        return self.contact_force()

    def save(self) -> tuple:
        """What a load step that fails goes back to: approach, displacement, multipliers."""
        previous = (self._previous[0], self._previous[1].copy())
        return self.delta, self.u.x.array.copy(), previous, self.contact.multipliers()

    def restore(self, snapshot: tuple) -> None:
        """Go back to a :meth:`save` snapshot (collective)."""
        self.delta, u, self._previous, multipliers = snapshot
        self.u.x.array[:] = u
        self.u.x.scatter_forward()
        self.minus_approach.value = -self.delta
        self.contact.set_multipliers(multipliers)

    def contact_force(self) -> float:
        """Total (full-ball) contact force along z (N)."""
        return SYMMETRY_FACTOR * float(self.contact.resultants()["ball"]["force"][2])

    def contact_radius(self, res: dict) -> float:
        """Contact radius (m) of the full ball from the quarter's contact area in ``res``."""
        return math.sqrt(SYMMETRY_FACTOR * res["area"] / math.pi)

    def top_reaction(self) -> float:
        """Total force (N, along z) the driven face exerts on the ball, from the FE residual."""
        return self._reaction(self._top_dofs)

    def bottom_reaction(self) -> float | None:
        """Total force (N, along z) the support exerts on the block (None: rigid counterpart)."""
        return None if self._bottom_dofs is None else self._reaction(self._bottom_dofs)

    def _reaction(self, dofs: np.ndarray) -> float:
        vec = fem_petsc.assemble_vector(self._internal_form)
        vec.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        n_owned = self.V.dofmap.index_map.size_local * 3
        local = float(np.sum(vec.array_r[dofs[dofs < n_owned]]))
        vec.destroy()
        return SYMMETRY_FACTOR * self.u.function_space.mesh.comm.allreduce(local, op=MPI.SUM)

    def reach(self, force: float, step: str) -> float:
        """Find the approach giving a contact force ``force`` (secant); return it."""
        model = self.model
        tol = model.force_tolerance * force
        d0 = max(self.delta, 0.0)
        f0 = self.contact_force() if d0 > 0 else 0.0
        # predictor: Hertz's increment of approach from f0 to force
        d1 = d0 + model.theory(force).approach - (model.theory(f0).approach if f0 > 0 else 0.0)
        f1 = self.solve(d1, step)
        for _ in range(MAX_FORCE_ITERATIONS):
            if abs(f1 - force) <= tol:
                return d1
            if f1 != f0 and d1 != d0:
                d2 = d1 + (force - f1) * (d1 - d0) / (f1 - f0)
            else:
                d2 = d1 * 1.1
            if f1 <= 0 or d2 <= 0:  # no contact yet: move by Hertz's estimate
                d2 = d1 + model.theory(force).approach
            d0, f0, d1 = d1, f1, d2
            f1 = self.solve(d1, step)
        if abs(f1 - force) <= tol:
            return d1
        raise ConvergenceError(
            f"{step}: contact force {f1:.6g} N, target {force:.6g} N",
            "DIVERGED_FORCE_MATCH",
            MAX_FORCE_ITERATIONS,
            self.solver.prefix,
        )

    def pressure_profile(self) -> tuple[np.ndarray, np.ndarray]:
        """(r, p) of the active quadrature points, on rank 0 sorted by r (others: empty)."""
        st = self.contact.point_state(0)
        xq, p = st["xq"], st["p"]
        a = p > 0
        r = np.hypot(xq[a, 0], xq[a, 1])
        comm = self.u.function_space.mesh.comm
        parts = comm.gather((r, p[a]), root=0)
        if comm.rank != 0:
            return np.zeros(0), np.zeros(0)
        r = np.concatenate([x[0] for x in parts])
        p = np.concatenate([x[1] for x in parts])
        order = np.argsort(r)
        return r[order], p[order]
