"""Method ``decoupled``, part 2: the scapula alone, linear elastic in its floating frame.

Paper eq. 13: K u = R^T f (part 1's transferred loads) + springs + the rigid-frame inertia and
Coriolis loads of the recorded motion (the rotation takes ``rotation_duration``), with an
inertia relief that leaves only the self-equilibrated part of the inertia. One factorization
serves every angle (chord iterations; only the springs' geometric terms are nonlinear).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING

import dolfinx
import numpy as np
import ufl
from mpi4py import MPI
from petsc4py import PETSc
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from shoulder_fem.engine.gamg import scaled_gamg_options
from shoulder_fem.engine.rigid_system import RigidBody, RigidSystem, Tie
from shoulder_fem.engine.so3 import hat
from shoulder_fem.engine.solver import StepperStats
from shoulder_fem.engine.springs import GROUND, Spring, spring_response
from shoulder_fem.families.base import RunContext
from shoulder_fem.families.shoulder.geometry import gather_rows, patch_centroid
from shoulder_fem.families.shoulder.interactions import bone_fields, surfaces
from shoulder_fem.families.shoulder.measures import VonMises
from shoulder_fem.families.shoulder.model import ShoulderModel
from shoulder_fem.families.shoulder.outputs import record_time_split, record_von_mises
from shoulder_fem.forms import materials
from shoulder_fem.forms import virtual_power as vp
from shoulder_fem.io.fields import FieldWriter
from shoulder_fem.io.results import Recorder
from shoulder_fem.meshes import shoulder as S

if TYPE_CHECKING:
    from shoulder_fem.families.shoulder.decoupled import Transfer

__all__ = [
    "CHORD_OPTIONS",
    "FloatingBone",
    "FrameInertia",
    "NodalLoads",
    "SurfaceForces",
    "finite_differences",
    "owned_nodes",
    "run_part2",
    "solver_options",
]

#: Newton settings of part 2: the Jacobian of the first solve is kept (chord iterations).
CHORD_OPTIONS = {
    "snes_lag_jacobian": -2,
    "snes_lag_jacobian_persists": True,
    "snes_lag_preconditioner": -2,
    "snes_lag_preconditioner_persists": True,
    # chord iterations converge linearly (rate ~0.15) to a round-off floor of ~3e-10 N
    "snes_rtol": 1e-8,
    "snes_atol": 1e-8,
    "snes_max_it": 50,
}


def owned_nodes(V, points: np.ndarray, what: str) -> tuple[np.ndarray, np.ndarray]:
    """Which of ``points`` (m, the same on every rank) are nodes this rank owns (collective).

    Returns:
        (their indices in ``points``, their local node indices in ``V``).

    Raises:
        ValueError: A point that is no node of ``V`` (``what`` names the points).
    """
    comm = V.mesh.comm
    n_owned = V.dofmap.index_map.size_local
    X = V.tabulate_dof_coordinates()[:n_owned]
    if n_owned and len(points):
        dist, idx = cKDTree(X).query(points)
    else:
        dist, idx = np.full(len(points), np.inf), np.zeros(len(points), dtype=np.int64)
    mine = np.flatnonzero(dist < 1e-9)
    found = np.zeros(len(points), dtype=np.int32)
    found[mine] = 1
    missing = np.flatnonzero(comm.allreduce(found, op=MPI.SUM) != 1)
    if len(missing):
        raise ValueError(
            f"{what}: {len(missing)} of {len(points)} points are no node of the bone's mesh "
            f"(e.g. {points[missing[0]].tolist()} m)"
        )
    return mine, idx[mine]


class SurfaceForces:
    """The nodal forces part 1's soft tissues apply on given surfaces of a bone (collective).

    The loads that :class:`NodalLoads` gives a bone's floating-frame problem: minus part 1's
    FE residual at the P2 nodes of the facets tagged ``tags``.

    Attributes:
        points: The nodes (m, reference geometry), gathered on every rank.
    """

    def __init__(self, V, facet_tags, tags: list[int]):
        self.comm = V.mesh.comm
        n_owned = V.dofmap.index_map.size_local
        facets = [facet_tags.find(t) for t in tags]
        dofs = np.unique(
            np.concatenate([dolfinx.fem.locate_dofs_topological(V, 2, f) for f in facets])
        )
        self.dofs = dofs[dofs < n_owned]
        self.points = gather_rows(V.tabulate_dof_coordinates()[self.dofs], self.comm)

    def __call__(self, residual: PETSc.Vec) -> np.ndarray:
        """The forces (N, (n, 3), world frame) at :attr:`points` under ``residual``, gathered."""
        return gather_rows(-residual.array_r.reshape(-1, 3)[self.dofs], self.comm)


class NodalLoads:
    """Given nodal forces (N) on a :class:`RigidSystem`, through its contact hook.

    External loads: subtracted from the residual; no tangent.
    """

    def __init__(self, V, points: np.ndarray, what: str = "decoupled part 2: transferred loads"):
        self.comm = V.mesh.comm
        self._mine, self._rows = owned_nodes(V, points, what)
        self.forces = np.zeros((len(points), 3))

    def add_residual(self, b: PETSc.Vec) -> None:
        """Subtract the forces from the owned rows of the (full) residual ``b``."""
        with b.localForm() as loc:
            arr = loc.array.reshape(-1, 3)
            arr[self._rows] -= self.forces[self._mine]

    def jacobian_matrix(self, K: PETSc.Mat, reuse: PETSc.Mat | None = None) -> PETSc.Mat:
        """An empty matrix of ``K``'s layout (dead loads have no tangent); ``reuse`` if given."""
        if reuse is not None:
            return reuse
        A = PETSc.Mat().createAIJ(K.getSizes(), nnz=1, comm=self.comm)
        A.setUp()
        A.assemble()
        return A


def finite_differences(
    times: np.ndarray, translations: np.ndarray, rotations: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per output: velocity, acceleration (spatial) and body-frame Ω, dΩ/dt (backward).

    ``times`` (s), ``translations`` (m, (n, 3)), ``rotations`` ((n, 3, 3)); the first output's
    rates are zero.
    """
    n = len(times)
    vel, acc = np.zeros((n, 3)), np.zeros((n, 3))
    om, dom = np.zeros((n, 3)), np.zeros((n, 3))
    for k in range(1, n):
        dt = times[k] - times[k - 1]
        vel[k] = (translations[k] - translations[k - 1]) / dt
        acc[k] = (vel[k] - vel[k - 1]) / dt
        om[k] = Rotation.from_matrix(rotations[k - 1].T @ rotations[k]).as_rotvec() / dt
        dom[k] = (om[k] - om[k - 1]) / dt
    return vel, acc, om, dom


class FrameInertia:
    """The floating frame's inertia loads on the scapula, and their relief (collective).

    Frame acceleration a0 + dΩ x r + Ω x (Ω x r) (r from ``ref``) and Coriolis 2 Ω x du/dt,
    floating-frame components. Inertia relief: part 1 is quasi-static, so its transferred
    loads balance the springs without the inertia of the rigid motion; the resultant of the
    frame inertia (force and moment) has nothing to balance it and would only drive a rigid
    motion of the floating frame on the soft suspension. A rigid acceleration field
    a + alpha x r that cancels it is added: the scapula is loaded by the self-equilibrated part
    of its inertia.
    """

    def __init__(self, mesh, rho, u, u_prev, ref: np.ndarray, dx):
        self.comm = mesh.comm
        self.rho, self.dx = rho, dx
        self.a0 = dolfinx.fem.Constant(mesh, np.zeros(3))
        self.om = dolfinx.fem.Constant(mesh, np.zeros(3))
        self.dom = dolfinx.fem.Constant(mesh, np.zeros(3))
        self.inv_dt = dolfinx.fem.Constant(mesh, 0.0)
        self.relief_a = dolfinx.fem.Constant(mesh, np.zeros(3))
        self.relief_alpha = dolfinx.fem.Constant(mesh, np.zeros(3))
        # the reference point as a constant: another geometry compiles no new form
        self.ref = dolfinx.fem.Constant(mesh, np.asarray(ref, dtype=PETSc.ScalarType))
        self.r = r = ufl.SpatialCoordinate(mesh) - self.ref
        om, dom = self.om, self.dom
        self.a_frame = self.a0 + ufl.cross(dom, r) + ufl.cross(om, ufl.cross(om, r))
        self.a_cor = 2 * ufl.cross(om, (u - u_prev) * self.inv_dt)
        self.a_relief = self.relief_a + ufl.cross(self.relief_alpha, r)

    def residual(self, w) -> ufl.Form:
        """The inertia's virtual power on test function ``w`` (frame, relief and Coriolis)."""
        return ufl.inner(self.rho * (self.a_frame + self.a_relief + self.a_cor), w) * self.dx

    def compile(self) -> None:
        """Compile the resultant forms and assemble the relief's 6 x 6 mass matrix about ref."""
        rho, dx, r, a_frame = self.rho, self.dx, self.r, self.a_frame
        self.inertia_forms = [dolfinx.fem.form(rho * a_frame[i] * dx) for i in range(3)]
        self.inertia_forms += [
            dolfinx.fem.form(rho * ufl.cross(r, a_frame)[i] * dx) for i in range(3)
        ]
        self.coriolis_forms = [dolfinx.fem.form(rho * self.a_cor[i] * dx) for i in range(3)]
        mass = self._integral(rho)
        first = np.array([self._integral(rho * r[i]) for i in range(3)])
        second = np.array([[self._integral(rho * r[i] * r[j]) for j in range(3)] for i in range(3)])
        # [m I, -hat(S); hat(S), J] (a, alpha) = -(F, M), J = tr(R2) I - R2 about ref
        self.relief_matrix = np.block(
            [
                [mass * np.eye(3), -hat(first)],
                [hat(first), np.trace(second) * np.eye(3) - second],
            ]
        )

    def _integral(self, expr) -> float:
        return self.comm.allreduce(
            dolfinx.fem.assemble_scalar(dolfinx.fem.form(expr * self.dx)), op=MPI.SUM
        )

    def _assemble(self, forms) -> np.ndarray:
        return np.array(
            [self.comm.allreduce(dolfinx.fem.assemble_scalar(g), op=MPI.SUM) for g in forms]
        )

    def relieve(self, couple: np.ndarray | None = None) -> np.ndarray:
        """Set the relief that cancels the frame inertia's resultant; returns that (F, M).

        ``couple`` (N m, floating frame): a couple that the relief also applies to the body.
        """
        resultant = self._assemble(self.inertia_forms)
        target = -resultant
        if couple is not None:  # the relief's inertia resultant is minus the load it applies
            target[3:] -= couple
        relief = np.linalg.solve(self.relief_matrix, target)
        self.relief_a.value[:], self.relief_alpha.value[:] = relief[:3], relief[3:]
        return resultant

    def coriolis(self) -> np.ndarray:
        """The resultant of the Coriolis loads (N) at the current state."""
        return self._assemble(self.coriolis_forms)


class FloatingBone:
    """One bone alone, linear elastic in its floating frame (paper eq. 13) (collective).

    Its P2 displacement ``u`` (floating-frame components), the frame's inertia about ``ref``
    with its relief (:class:`FrameInertia`), the residual, and the rates of part 1's recorded
    rigid motion at the output angles (the rotation takes ``rotation_duration`` to reach
    ``final_angle``). Part 2's scapula (:class:`_Part2`) and the compliant decoupling's humerus
    (:mod:`.humerus`) are two.

    Args:
        model: The decoupled model; ``variant`` names the bone's mesh in it.
        ref: The floating frame's reference point (m).
        angles: The output angles (rad).
        translation: Per output, the bone's rigid translation (m).
        rotation: Per output, its rigid rotation (3 x 3).
        name: The displacement's name in the output fields.
    """

    def __init__(
        self,
        model: ShoulderModel,
        variant: str,
        ref: np.ndarray,
        angles,
        translation,
        rotation,
        name: str = "displacement",
    ):
        p = model.params
        bm = model.meshes[variant]
        self.mesh, self.cell_tags, self.ft = mesh, ct_, _ = bm.mesh, bm.cell_tags, bm.facet_tags
        self.comm = mesh.comm
        V = self.V = dolfinx.fem.VectorFunctionSpace(mesh, ("Lagrange", 2))
        u = self.u = dolfinx.fem.Function(V, name=name)
        self.u_prev = dolfinx.fem.Function(V)
        w = ufl.TestFunction(V)
        dx = ufl.Measure("dx", domain=mesh, subdomain_data=ct_, metadata=p.quadrature())
        rho, E = bone_fields(mesh, ct_, model.image, p)
        self.law = materials.LinearElastic(E, materials.BONE_NU)
        self.inertia = FrameInertia(mesh, rho, u, self.u_prev, ref, dx)
        self.residual = vp.internal_power_linear(self.law, u, w, dx) + self.inertia.residual(w)
        self.inertia.compile()
        self.angles = np.asarray(angles)
        self.times = self.angles / p.final_angle * p.rotation_duration
        self.T, self.R = np.asarray(translation), np.asarray(rotation)
        _, self.acc, self.omega, self.domega = finite_differences(self.times, self.T, self.R)

    def frame_motion(self, k: int) -> None:
        """Set the frame's acceleration, Ω, dΩ/dt and the Coriolis rate of output ``k``."""
        inertia = self.inertia
        inertia.a0.value[:] = self.R[k].T @ self.acc[k]
        inertia.om.value[:] = self.omega[k]
        inertia.dom.value[:] = self.domega[k]
        inertia.inv_dt.value = 1.0 / (self.times[k] - self.times[k - 1]) if k > 0 else 0.0


def solver_options(params, run: RunContext) -> tuple[dict, bool]:
    """A floating bone's SNES options, and whether they are iterative.

    Chord iterations; CG + GAMG with ``part2_solver = iterative``, else LU.
    """
    iterative = params.part2_solver == "iterative"
    # CG to 1e-5 per chord step (the SNES still converges to its own 1e-8): measured at
    # paper, 21 chord steps and 729 CG iterations against 18 and 1 105 at 1e-8 (8.2 s, 11.0 s)
    linear = scaled_gamg_options(rtol=1e-5) if iterative else {}
    return CHORD_OPTIONS | linear | dict(run.options or {}), iterative


def _suspension(
    mesh, ft, layout: list[dict], length: float
) -> tuple[list[RigidBody], list[Tie], list[Spring], list[Spring]]:
    """The scapula's springs, each on a rigid plate tied to its patch (collective).

    What part 2 does with a spring: its force at the recorded pose (the rigid scapula of part
    1; floating-frame components) is a given force on its plate, and the plate's motion in the
    floating frame adds the exact response of a spring of the same stiffness that has no force
    at the reference pose (its ground end fixed in the floating frame). The recorded tension's
    own geometric stiffness N/l (the turning of a loaded spring) is left out: its size against
    k is the series ``part2_spring_geometric_stiffness_ratio``, and the plates' motion the
    series ``part2_spring_plate_displacement`` (README). The Jacobian is that of the reference
    pose (chord iterations), so one factorization serves every angle.

    Returns:
        (plates, ties, springs on the plates, the same springs on the rigid scapula).
    """
    bodies, ties, springs, world = [], [], [], []
    for sp in layout:
        if sp["bone"] != "scapula":
            continue
        # part 1's attachment point (``centre``, set by part 1) when there is one: the springs
        # then act where part 1's did, on a part-2 mesh of another level too
        c = sp.get("centre")
        c = patch_centroid(mesh, ft, S.MARKERS[sp["name"]].id) if c is None else np.asarray(c)
        bodies.append(RigidBody(sp["name"], c))
        ties.append(Tie(sp["name"], sp["name"]))
        end = c + length * sp["direction"]
        springs.append(Spring(sp["name"], sp["name"], c, GROUND, end, sp["stiffness"]))
        world.append(Spring(sp["name"], "scapula", c, GROUND, end, sp["stiffness"]))
    return bodies, ties, springs, world


class _Part2(FloatingBone):
    """The scapula's floating-frame problem over part 1's output angles (collective)."""

    def __init__(
        self,
        model: ShoulderModel,
        run: RunContext,
        transfer: Transfer,
        layout: list[dict],
        recorder: Recorder | None = None,
        write_fields: bool = True,
    ):
        p = model.params
        tr = transfer
        super().__init__(model, "scapula", tr.reference, tr.angles, tr.translation, tr.rotation)
        mesh, ct_, ft, V, u = self.mesh, self.cell_tags, self.ft, self.V, self.u
        self.recorder = run.recorder if recorder is None else recorder
        self.transfer, self.ref = transfer, transfer.reference
        self.loads = NodalLoads(V, transfer.points)
        self.bodies, ties, springs, self.world = _suspension(mesh, ft, layout, p.spring_length)
        self.plate_springs = springs
        options, iterative = solver_options(p, run)
        self.system = RigidSystem(
            self.bodies,
            springs,
            u=u,
            residual=self.residual,
            surfaces=surfaces(ft, [t.surface for t in ties]),
            ties=ties,
            name="shoulder_part2",
            options=options,
            form_compiler_params=p.quadrature(),
            contact=self.loads,
            linear_ties=True,
            near_nullspace=iterative,
        )
        self.stress_vm = VonMises(mesh, ct_, self.law.stress(ufl.sym(ufl.grad(u))), p.nodal_stress)
        self.writer = (
            FieldWriter(self.comm, mesh, run.fields / "part2.xdmf") if write_fields else None
        )
        P1 = dolfinx.fem.VectorFunctionSpace(mesh, ("Lagrange", 1))
        self.u1 = dolfinx.fem.Function(P1)  # at the vertices, for the global frame's fields
        # ParaView's global-frame fields: the scapula where part 1 moved it, and its stress
        self.u_global = dolfinx.fem.Function(P1, name="displacement_global")
        self._X1 = P1.tabulate_dof_coordinates()
        self.stress_global = None  # the scalar recipe has no tensor to turn
        if p.nodal_stress == "tensor":
            T = self.stress_vm.recovery.tensor.function_space
            self.stress_global = dolfinx.fem.Function(T, name="stress_global")
        self.iterations = 0
        self.worst = 0.0

    def _load(self, k: int, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Apply output ``k``'s transferred forces ``f`` and springs at the recorded pose.

        Floating-frame components; returns their force and moment sums (world frame), where
        part 1 balanced them: with a compliant part 1 (:mod:`.correction`), at the surfaces
        and spring attachments it had moved by ``o``. Part 2 then takes each spring's force
        there, with its response to the plate's motion from ``o`` (the plate is at ``o`` when
        part 2 finds the deformation part 1 assumed), and the couple by which ``o`` turns the
        loads, ``sum o x f``, which it applies through the inertia relief: part 2's linear
        balance is about the reference shape.
        """
        ref, points = self.ref, self.transfer.points
        Rk, tk = self.R[k], self.T[k]
        self.loads.forces[:] = f @ Rk  # R^T f per row: floating-frame components
        centre = ref + tk
        tr = self.transfer
        springs = tr.spring_offsets[k] if tr.spring_offsets else {}
        #: The couple (N m, floating frame) by which a compliant part 1's offsets turn the
        #: loads (see above); zero otherwise.
        self.offset_couple = np.zeros(3)
        if tr.point_offsets:
            moved = np.asarray(tr.point_offsets[k])
            self.offset_couple += np.cross(moved, f @ Rk).sum(axis=0)
            points = points + moved
        fs, ms = f.sum(axis=0), np.cross(points - ref, f @ Rk).sum(axis=0)
        ms = Rk @ ms
        self.geometric_ratio = 0.0
        plates = zip(self.bodies, self.world, self.plate_springs, strict=True)
        for body, sp, plate in plates:
            o = np.asarray(springs.get(sp.name, np.zeros(3)))
            pa = centre + Rk @ (np.asarray(sp.point_a) + o - ref)
            response = spring_response(sp, pa, np.asarray(sp.point_b))
            g = response.gradient
            body.force = -Rk.T @ g
            if sp.name in springs:  # the plate spring's response from o, not from 0
                moved = np.asarray(plate.point_a) + o
                body.force += spring_response(plate, moved, np.asarray(plate.point_b)).gradient
                self.offset_couple += np.cross(o, -Rk.T @ g)
            fs, ms = fs - g, ms + np.cross(pa - centre, -g)
            # the recorded tension's geometric stiffness N/l, left out of part 2, against k
            ratio = abs(response.tension) / response.length / sp.stiffness
            self.geometric_ratio = max(self.geometric_ratio, ratio)
        return fs, ms

    def step(self, k: int, target: float, data: dict) -> None:
        """Solve at output ``k`` (angle ``target`` rad) and record its outputs."""
        inertia, rec, comm = self.inertia, self.recorder, self.comm
        x = math.degrees(target)
        f = np.asarray(self.transfer.forces[k])
        fs, ms = self._load(k, f)
        self.frame_motion(k)
        resultant = inertia.relieve(self.offset_couple)
        self.iterations += self.system.solve(step=f"part2 {x:.0f} deg")
        # equilibrium of the transferred loads with the springs at the recorded rigid pose,
        # relative to the loads, or in N below 1 N of them (the open unloaded joint's loads of
        # about 1e-3 N: their round-off relative to them read up to 0.86 on 2 ranks)
        scale = max(float(np.abs(f).sum()), 1.0)
        lever = float(np.linalg.norm(self.transfer.points - self.ref, axis=1).max())
        resid = max(float(np.linalg.norm(fs)) / scale, float(np.linalg.norm(ms)) / (scale * lever))
        self.worst = max(self.worst, resid)
        rec.add_series_point("transfer_equilibrium_residual", x, resid, "deg", "1")
        rec.add_series_point(
            "part2_spring_geometric_stiffness_ratio", x, self.geometric_ratio, "deg", "1"
        )
        plate = max(float(np.linalg.norm(b.translation)) for b in self.bodies)
        rec.add_series_point("part2_spring_plate_displacement", x, plate, "deg", "m")
        coriolis = inertia.coriolis()
        rec.add_series_point(
            "part2_inertia_force", x, float(np.linalg.norm(resultant[:3])), "deg", "N"
        )
        rec.add_series_point(
            "part2_inertia_moment", x, float(np.linalg.norm(resultant[3:])), "deg", "N m"
        )
        rec.add_series_point("part2_coriolis_force", x, float(np.linalg.norm(coriolis)), "deg", "N")
        rec.add_series_point(
            "part2_transferred_force", x, float(np.linalg.norm(f, axis=1).sum()), "deg", "N"
        )
        record_von_mises(rec, self.stress_vm, x, data, comm)
        if self.writer is not None:
            self.u1.interpolate(self.u)
            self.writer.write([self.u, *self.stress_vm.fields(), *self._global_fields(k)], x)
        self.u_prev.x.array[:] = self.u.x.array

    def _global_fields(self, k: int) -> list:
        """Output ``k``'s displacement and stress in the global frame (at the last update).

        A point X of the floating frame, displaced by u there, is at
        x = ref + T + R (X + u - ref) (part 1's rigid motion T, R of the scapula); the stress
        turns as R σ Rᵀ.
        """
        R, T, X = self.R[k], self.T[k], self._X1
        x = self.ref + T + (X + self.u1.x.array.reshape(-1, 3) - self.ref) @ R.T
        self.u_global.x.array[:] = (x - X).ravel()
        if self.stress_global is None:
            return [self.u_global]
        sig = self.stress_vm.recovery.tensor.x.array.reshape(-1, 3, 3)
        self.stress_global.x.array[:] = np.einsum("ij,njk,lk->nil", R, sig, R).ravel()
        return [self.u_global, self.stress_global]

    def finish(self) -> None:
        """Record the probes and counters, free the solver."""
        rec = self.recorder
        rec.set_probe("transfer_equilibrium_residual", self.worst, "1")
        rec.set_probe("part2_factorizations", self.system.stats.factorizations, "1")
        rec.set_probe("part2_iterations", self.iterations, "1")
        rec.set_probe("part2_krylov_iterations", self.system.stats.krylov_iterations, "1")
        record_time_split(rec, "part2", self.system, None)
        rec.add_solver_counts(self.system.stats, StepperStats(steps=len(self.angles)))
        rec.extra("dofs_part2", self.V.dofmap.index_map.size_global * 3)
        self.system.destroy()


def run_part2(
    model: ShoulderModel,
    run: RunContext,
    transfer: Transfer,
    layout: list[dict],
    data: dict,
    *,
    recorder: Recorder | None = None,
    write_fields: bool = True,
    on_step: Callable[[int, _Part2], None] | None = None,
) -> tuple[VonMises, dolfinx.mesh.Mesh, dolfinx.mesh.MeshTags]:
    """The scapula in its floating frame, linear elastic, one factorization (collective).

    Args:
        model: The decoupled model (its ``scapula`` mesh).
        run: The run's context.
        transfer: Part 1's :class:`~shoulder_fem.families.shoulder.decoupled.Transfer`.
        layout: The flexible elements (:func:`interactions.spring_layout`).
        data: The stepping's outputs; the von Mises stress of the last angle is added.
        recorder: Where its series, probes and counters go (default the run's).
        write_fields: Write ``part2.xdmf``.
        on_step: Called with (output index, the part-2 problem) after each angle's solve.

    Returns:
        (the von Mises operator, the scapula mesh, its facet tags), for ``shoulder.npz``.
    """
    part2 = _Part2(model, run, transfer, layout, recorder, write_fields)
    try:
        for k, target in enumerate(part2.angles):
            part2.step(k, target, data)
            if on_step is not None:
                on_step(k, part2)
    finally:
        if part2.writer is not None:
            part2.writer.close()
    part2.finish()
    return part2.stress_vm, part2.mesh, part2.ft
