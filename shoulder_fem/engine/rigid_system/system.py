"""Rigid bodies inside finite-element models: tied surfaces, springs, loads; a reduced system.

Unknowns. The reduced unknown vector holds every free displacement DOF of the deformable body
(not tied, not fixed) and six DOFs per rigid body: the translation ``t`` of its reference point
(m) and an incremental rotation vector ``φ`` (rad) measured from the body's rotation ``R₀`` at
the start of the current solve, ``R = exp(hat φ) R₀``. At the end of every converged solve
``R₀ ← R`` and ``φ ← 0``: rotations are composed on SO(3), angles are never added across solves.
The rigid DOFs are owned by **rank 0** (the last entries of its local block); every rank builds
the same layout.

Tied surfaces. A node of a tied surface with reference position X follows its body exactly,
``x = X_ref + t + R (X - X_ref)``, so its displacement is a function of the six DOFs and distances
between tied nodes are preserved to round-off at any rotation.

Prolongation. ``P`` (PETSc MPIAIJ, rows = all FE DOFs, columns = reduced DOFs) maps a reduced
correction to a displacement correction: identity on free DOFs, zero rows on fixed DOFs and on a
tied node i, with ``r_i = R (X_i - X_ref)``,

    δu_i = δt + δθ × r_i = δt - hat(r_i) J_l(φ) δφ,

where δθ is the spatial rotation increment and ``J_l(φ) = J_r(-φ)`` the left Jacobian of SO(3).

Residual and tangent. With F the FE residual (internal minus external forces, N) assembled
without boundary conditions, the reduced residual is ``r = Pᵀ F + r_rigid``, where for body b
``r_rigid`` holds ``-(applied force) + Σ_springs dE/dt`` and ``J_lᵀ (-(applied moment) +
Σ_springs dE/dθ)``. Its rows for body b say that the tie forces, springs and loads on b balance:
``Σ f_i - F_springs - F_applied = 0`` and ``Σ r_i × f_i - M_springs - M_applied = 0``.
The reduced Jacobian is ``Pᵀ K P`` (``K.PtAP(P)``) plus, per body, the rotation's geometric term:
``r_i`` turns with the body, δ(r_i × f_i) = (δθ × r_i) × f_i = hat(f_i) hat(r_i) δθ, so

    G_θθ = Σ_i hat(f_i) hat(r_i)      (not symmetric away from equilibrium),

mapped to φ by ``J_lᵀ G J_l``, plus the springs' tangents (see :mod:`shoulder_fem.springs`), plus
``∂(J_l(φ)ᵀ m)/∂φ`` with m the body's spatial moment residual (it vanishes at equilibrium, but
keeping it makes the tangent exact everywhere: the Taylor test passes at any state, tested).

Prescribed bodies take their six DOFs from :meth:`RigidBody.prescribe`; their rows and columns
of the Jacobian become the identity and their residual rows zero (Dirichlet-like). In a static
system (the default) a free body that nothing holds (no tie, no spring) is rejected when the
system is built, before any solve.

Dynamics (``RigidSystem(..., dynamic=True)`` and :meth:`RigidSystem.step`). A body given a mass m
and a body-frame inertia I_G about its centre of mass G (:meth:`RigidBody.set_mass_properties`,
e.g. from :func:`mass_properties`) is integrated in time; the deformable body stays
quasi-static (its residual carries no inertia), massless bodies stay quasi-static too, and
prescribed bodies follow their prescription. The scheme is the Simo–Wong energy–momentum
algorithm of :class:`shoulder_fem.rigid.NewtonEuler` with the loads averaged over the step
(trapezoidal rule) instead of sampled at the mid-step state, so that the quasi-static FE
equilibrium and the tie forces are those of the end of the step. From state n (centre x_n,
velocity v_n, rotation R_n, body angular velocity Ω_n, spatial angular momentum
L_n = R_n I_G Ω_n, loads F_n and M_n about G) to n+1, with R_{n+1} = R_n exp(hat θ)
(θ = R_nᵀ φ: body increment; the reduced DOFs are unchanged)::

    m (v_{n+1} - v_n) = h (F_n + F_{n+1}) / 2,      x_{n+1} = x_n + h (v_n + v_{n+1}) / 2,
    L_{n+1} - L_n     = h (M_n + M_{n+1}) / 2,      θ = h (Ω_n + Ω_{n+1}) / 2.

Eliminating v_{n+1} and Ω_{n+1}, the body's residual rows (2/h times the momentum balances) are

    f_I = (4m/h²)(x_{n+1} - x_n - h v_n) - F_n,
    m_I = (2/h)(R_{n+1} I_G (2θ/h - Ω_n) - L_n) - M_n,

added to the static rows as ``(f_I, m_I + ρ × f_I)`` (ρ = x_G - x_ref: the moment rows are about
the reference point), whose static part is ``-(F_{n+1}, M_{n+1} + ρ × F_{n+1})``. Their exact
derivatives with respect to (t, φ) enter the same reduced Jacobian. Properties (tested):
second order; a constant moment about a principal axis gives θ = M t²/(2I) to round-off;
torque-free, L and the kinetic energy are conserved to the solver tolerance (θ is an
eigenvector of exp(-hat θ), as in Simo–Wong); a linear spring oscillator conserves its energy and
has the trapezoidal rule's period error (ωh)²/12.
"""

from __future__ import annotations

import contextlib
import logging
import math
import time
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field

import dolfinx
import dolfinx.fem.petsc as fem_petsc
import numpy as np
import ufl
from mpi4py import MPI
from petsc4py import PETSc

from shoulder_fem.engine.fem import owned_flags
from shoulder_fem.engine.mass import MassProperties
from shoulder_fem.engine.rigid import RigidState
from shoulder_fem.engine.so3 import exp_so3, hat, hats, log_so3, right_jacobian
from shoulder_fem.engine.solver import (
    ConvergenceError,
    SolveStats,
    default_snes_options,
    reason_name,
    set_from_options,
    unique_prefix,
)
from shoulder_fem.engine.springs import GROUND, Spring, spring_response

logger = logging.getLogger(__name__)

__all__ = ["RigidBody", "RigidSystem", "Tie"]


@contextlib.contextmanager
def _timed(stats: SolveStats, name: str) -> Iterator[None]:
    """Add the wall time of the enclosed block to ``stats.<name>`` (s), even if it raises."""
    t0 = time.perf_counter()
    try:
        yield
    finally:
        setattr(stats, name, getattr(stats, name) + time.perf_counter() - t0)


def _left_jacobian(phi: np.ndarray) -> np.ndarray:
    """Left Jacobian of SO(3), ``exp(hat(φ + δ)) ≈ exp(hat(J_l δ)) exp(hat φ)``."""
    return right_jacobian(-np.asarray(phi, dtype=float))


def _d_jr_times(phi: np.ndarray, m: np.ndarray) -> np.ndarray:
    """∂(J_r(φ) m)/∂φ for a fixed vector m: (3, 3).

    J_r m = m - b φ×m + c φ×(φ×m), b = (1 - cos θ)/θ², c = (θ - sin θ)/θ³, θ = |φ|, so
    ∂/∂φ = b hat(m) - (φ×m)(b'/θ) φᵀ + c((φ·m) I + φ mᵀ - 2 m φᵀ) + (φ×(φ×m))(c'/θ) φᵀ.
    Below θ = 1e-3 the coefficients come from their Taylor series (error < 1e-16).
    """
    theta = float(np.linalg.norm(phi))
    t2 = theta * theta
    if theta < 1e-3:
        b = 0.5 - t2 / 24.0 + t2 * t2 / 720.0
        c = 1.0 / 6.0 - t2 / 120.0 + t2 * t2 / 5040.0
        db = -1.0 / 12.0 + t2 / 180.0
        dc = -1.0 / 60.0 + t2 / 1260.0
    else:
        s, co = math.sin(theta), math.cos(theta)
        b = (1.0 - co) / t2
        c = (theta - s) / theta**3
        db = (theta * s - 2.0 * (1.0 - co)) / theta**4
        dc = (1.0 - co) / theta**4 - 3.0 * (theta - s) / theta**5
    pm = np.cross(phi, m)
    ppm = np.cross(phi, pm)
    return (
        b * hat(m)
        - db * np.outer(pm, phi)
        + c * (float(phi @ m) * np.eye(3) + np.outer(phi, m) - 2.0 * np.outer(m, phi))
        + dc * np.outer(ppm, phi)
    )


@dataclass
class RigidBody:
    """A rigid body with six DOFs; with a mass and an inertia, a dynamic one.

    Attributes:
        name: Unique name (ties and springs refer to it).
        reference_point: Reference position X_ref of the point whose translation is a DOF (m).
        force: Applied force at the reference point, inertial frame (N).
        moment: Applied moment, inertial frame (N·m).
        prescribed: The motion is given by :meth:`prescribe` (Dirichlet-like on all six DOFs)
            instead of being solved for.
        translation: Current translation t of the reference point (m) (state).
        rotation: Current rotation R (3×3) (state).
        mass: Mass m (kg), > 0; ``None`` for a massless (quasi-static) body.
        inertia: Inertia tensor about the centre of mass in the body (= reference) frame I_G
            (kg m²), symmetric positive-definite (3, 3) or (3,) principal moments; required
            with ``mass``.
        centre: Reference position of the centre of mass X_G (m); default ``reference_point``.
        velocity: Velocity of the centre of mass, inertial frame (m/s) (state, dynamics).
        omega: **Body-frame** angular velocity Ω (rad/s), ``Ṙ = R hat(Ω)``, as in
            :mod:`shoulder_fem.rigid` (state, dynamics).

    Raises:
        ValueError: A mass that is not finite and > 0, an inertia that is not a finite
            symmetric positive-definite tensor, or one without the other (names the body).
    """

    name: str
    reference_point: np.ndarray
    force: np.ndarray = field(default_factory=lambda: np.zeros(3))
    moment: np.ndarray = field(default_factory=lambda: np.zeros(3))
    prescribed: bool = False
    translation: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    mass: float | None = None
    inertia: np.ndarray | None = None
    centre: np.ndarray | None = None
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    omega: np.ndarray = field(default_factory=lambda: np.zeros(3))
    _target: tuple[np.ndarray, np.ndarray] | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        self.reference_point = np.asarray(self.reference_point, dtype=float).reshape(3)
        self.force = np.asarray(self.force, dtype=float).reshape(3)
        self.moment = np.asarray(self.moment, dtype=float).reshape(3)
        self.translation = np.asarray(self.translation, dtype=float).reshape(3)
        self.rotation = np.asarray(self.rotation, dtype=float).reshape(3, 3)
        self.velocity = np.asarray(self.velocity, dtype=float).reshape(3)
        self.omega = np.asarray(self.omega, dtype=float).reshape(3)
        self.set_mass_properties(self.mass, self.inertia, self.centre)

    def set_mass_properties(
        self,
        mass: float | MassProperties | None,
        inertia: np.ndarray | None = None,
        centre: np.ndarray | None = None,
    ) -> None:
        """Give the body a mass, an inertia about its centre of mass and that centre.

        Args:
            mass: Mass m (kg), finite and > 0; or a :class:`MassProperties` (from
                :func:`mass_properties` of the body's mesh region, in the reference
                configuration), which then supplies all three; or ``None`` (massless).
            inertia: I_G in the body (= reference) frame (kg m²): symmetric positive-definite
                (3, 3), or (3,) principal moments.
            centre: Reference position X_G (m); default the reference point.

        Raises:
            ValueError: Bad values, naming the body and the value (before any solve).
        """
        if isinstance(mass, MassProperties):
            mass, inertia, centre = mass.mass, mass.inertia, mass.centre
        where = f"rigid body '{self.name}'"
        if mass is None:
            if inertia is not None:
                raise ValueError(f"{where}: an inertia tensor needs a mass (got mass None)")
            self.mass, self.inertia = None, None
        else:
            m = float(mass)
            if not (math.isfinite(m) and m > 0.0):
                raise ValueError(f"{where}: mass must be finite and > 0 kg, got {mass}")
            if inertia is None:
                raise ValueError(f"{where}: a mass of {m} kg needs an inertia tensor (kg m²)")
            self.mass, self.inertia = m, _check_inertia(inertia, where)
        c = self.reference_point if centre is None else centre
        c = np.asarray(c, dtype=float)
        if c.shape != (3,) or not np.all(np.isfinite(c)):
            raise ValueError(f"{where}: centre must be a finite 3-vector (m), got {centre}")
        self.centre = c.copy()

    def centre_position(self) -> np.ndarray:
        """Current position of the centre of mass x_G (m)."""
        return self.position(self.centre)

    def angular_momentum(self, point: np.ndarray | None = None) -> np.ndarray:
        """Spatial angular momentum (kg m²/s) about G, or about a fixed ``point`` (m)."""
        L = self.rotation @ (self.inertia @ self.omega)
        if point is not None:
            L = L + self.mass * np.cross(self.centre_position() - point, self.velocity)
        return L

    def linear_momentum(self) -> np.ndarray:
        """Linear momentum m v_G (kg m/s)."""
        return self.mass * self.velocity

    def kinetic_energy(self) -> float:
        """Kinetic energy m |v_G|²/2 + Ω·I_G Ω/2 (J)."""
        return 0.5 * self.mass * float(self.velocity @ self.velocity) + 0.5 * float(
            self.omega @ self.inertia @ self.omega
        )

    def state(self, time: float = 0.0) -> RigidState:
        """The body's dynamic state as a :class:`shoulder_fem.rigid.RigidState` (centre G)."""
        return RigidState(time, self.centre_position(), self.velocity, self.rotation, self.omega)

    def prescribe(self, translation: np.ndarray, rotation: np.ndarray) -> None:
        """Set the motion of a prescribed body for the next solve (m, rotation matrix)."""
        if not self.prescribed:
            raise ValueError(f"rigid body '{self.name}' is not prescribed")
        self._target = (np.asarray(translation, float).copy(), np.asarray(rotation, float).copy())

    def position(self, point: np.ndarray) -> np.ndarray:
        """Current position (m) of the body point whose reference position is ``point`` (m)."""
        return (
            self.reference_point
            + self.translation
            + self.rotation @ (np.asarray(point, float) - self.reference_point)
        )


def _check_inertia(inertia: np.ndarray, where: str) -> np.ndarray:
    """A finite symmetric positive-definite (3, 3) inertia (kg m²); (3,) = principal moments."""
    a = np.asarray(inertia, dtype=float)
    if a.shape == (3,):
        a = np.diag(a)
    if a.shape != (3, 3) or not np.all(np.isfinite(a)):
        raise ValueError(
            f"{where}: inertia must be a finite (3, 3) tensor or (3,) principal moments (kg m²),"
            f" got {np.asarray(inertia).tolist()}"
        )
    scale = float(np.max(np.abs(a)))
    if scale == 0.0 or float(np.max(np.abs(a - a.T))) > 1e-12 * scale:
        raise ValueError(f"{where}: inertia must be symmetric and nonzero, got {a.tolist()} kg m²")
    a = 0.5 * (a + a.T)
    eig = np.linalg.eigvalsh(a)
    if eig[0] <= 1e-14 * eig[-1]:
        raise ValueError(
            f"{where}: inertia must be positive-definite, got eigenvalues {eig.tolist()} kg m²"
        )
    return a


@dataclass(frozen=True)
class Tie:
    """The nodes of surface ``surface`` follow rigid body ``body`` exactly."""

    body: str
    surface: str


@dataclass
class BodyBalance:
    """Forces (N) and moments about the body's current reference point (N·m) acting on it.

    After a dynamic :meth:`RigidSystem.step` the inertia terms hold d'Alembert's force and
    moment of the step's end, ``-m a_{n+1}`` and ``-(dL/dt + ρ × m a_{n+1})`` of the scheme
    (zero otherwise), so that the sums still vanish to the solver tolerance.
    """

    tie_force: np.ndarray
    tie_moment: np.ndarray
    spring_force: np.ndarray
    spring_moment: np.ndarray
    applied_force: np.ndarray
    applied_moment: np.ndarray
    inertia_force: np.ndarray = field(default_factory=lambda: np.zeros(3))
    inertia_moment: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @property
    def force_sum(self) -> np.ndarray:
        """Net force (N): zero at equilibrium (dynamic equilibrium after a step)."""
        return self.tie_force + self.spring_force + self.applied_force + self.inertia_force

    @property
    def moment_sum(self) -> np.ndarray:
        """Net moment (N·m): zero at equilibrium (dynamic equilibrium after a step)."""
        return self.tie_moment + self.spring_moment + self.applied_moment + self.inertia_moment


@dataclass
class RigidSolveStats(SolveStats):
    """:class:`SolveStats` plus the residual-norm history of every solve and where the time went.

    Wall seconds of this rank: ``snes_s`` in the Newton solves in all, ``residual_s`` and
    ``jacobian_s`` in their residual and Jacobian evaluations (contact included); the rest of
    ``snes_s`` is the linear solves (factorizations). Within ``jacobian_s``: ``fe_assembly_s``
    (the FE residual and matrix) and ``reduction_s`` (the products Pᵀ K P of the FE and contact
    matrices and their merge).
    """

    residual_histories: list[list[float]] = field(default_factory=list)
    snes_s: float = 0.0
    residual_s: float = 0.0
    jacobian_s: float = 0.0
    fe_assembly_s: float = 0.0
    reduction_s: float = 0.0


class RigidSystem:
    """A system of a deformable body, rigid bodies, ties, springs and applied loads.

    Static by default (:meth:`solve`); with ``dynamic=True`` :meth:`step` also integrates the
    bodies that have a mass in time (see the module docstring for the scheme).

    Args:
        bodies: The rigid bodies (their states are updated in place by :meth:`solve` and
            :meth:`step`).
        springs: Springs between bodies and the ground (:mod:`shoulder_fem.springs`).
        u: Displacement of the deformable body (m), a 3D vector Lagrange function; ``None`` for
            a system of rigid bodies and springs only.
        residual: UFL residual F(u; w) of the deformable body (N), required with ``u``.
        surfaces: Named surfaces: ``{name: (facet MeshTags, tag id)}``; cell tags name a
            region whose every node is tied (a block of cells carried by a body).
        ties: Which surface follows which body.
        fixed: Names of surfaces whose nodes are fixed (zero displacement).
        jacobian: UFL tangent of ``residual``; ``ufl.derivative`` if omitted.
        comm: Communicator (taken from ``u``'s mesh when given).
        deformable: Name of the deformable body in :attr:`Spring.body_a` / ``body_b``: such an
            end is attached to the FE node at its point (which must be a node); on a tied node
            it moves with that rigid body, on a fixed node it is a ground point.
        name: Short name; the SNES options prefix is ``<name><n>_``.
        options: PETSc options over :func:`shoulder_fem.solver.default_snes_options`.
        form_compiler_params: Passed to ``dolfinx.fem.form``.
        dynamic: Enable :meth:`step`: bodies with a mass (not prescribed) carry inertia; such
            a body needs nothing to hold it. ``False`` (default): static, masses are ignored.
        time: Initial time (s) of a dynamic system (:attr:`time`).
        contact: Contact terms on ``u`` (built with no Dirichlet conditions): a contact
            surface whose nodes are tied to a rigid body moves with it and loads it.
        linear_ties: Small-rotation kinematics of the tied nodes, ``u = t + φ × (X - X_ref)``
            with φ the body's total rotation vector (``rotation = exp(hat φ)``), and no
            geometric (tie-load) terms: with a linear residual the reduced problem is then
            linear in the tied nodes (the springs keep their exact response). For a linear
            elastic body in its floating frame (decoupled part 2): finite rotations of plates
            tied to stiff bone make the residual quadratic in rotations of a mode that only
            soft springs hold, which ruins the convergence of a chord (one-factorization)
            iteration. Static only.

    Raises:
        ValueError: Duplicate body names, a tie to an unknown body or surface, an empty
            surface, a spring on an unknown body, a node both tied and fixed or tied twice,
            or a free rigid body that nothing holds (static scene, or massless in a dynamic
            one) -- all before any solve.
    """

    def __init__(
        self,
        bodies: Sequence[RigidBody],
        springs: Sequence[Spring] = (),
        *,
        u: dolfinx.fem.Function | None = None,
        residual: ufl.Form | None = None,
        surfaces: Mapping[str, tuple[dolfinx.mesh.MeshTags, int]] | None = None,
        ties: Sequence[Tie] = (),
        fixed: Sequence[str] = (),
        jacobian: ufl.Form | None = None,
        comm: MPI.Comm | None = None,
        deformable: str = "deformable",
        name: str = "rigid",
        options: dict | None = None,
        form_compiler_params: dict | None = None,
        dynamic: bool = False,
        time: float = 0.0,
        contact=None,
        linear_ties: bool = False,
    ) -> None:
        self.bodies = list(bodies)
        self.linear_ties = bool(linear_ties)
        if self.linear_ties and dynamic:
            raise ValueError("RigidSystem: linear_ties is for static systems")
        if self.linear_ties and any(not np.allclose(b.rotation, np.eye(3)) for b in self.bodies):
            raise ValueError("RigidSystem: linear_ties needs bodies that start unrotated")
        #: Contact terms (:class:`shoulder_fem.contact.Contact` on ``u``, built without bcs):
        #: added to the FE residual and tangent before the reduction, so that a master surface
        #: whose nodes are tied to a rigid body is a rigid contact surface.
        self.contact = contact
        self._contact_keys = np.zeros(0, dtype=np.int64)
        self.dynamic = bool(dynamic)
        #: Time (s) of the current state; advanced by :meth:`step`.
        self.time = float(time)
        self._dt: float | None = None  # step size while a dynamic step is being solved
        self._start_n: list | None = None  # per body: (x_G, v, R, Ω, L) at the step's start
        self._loads_n: np.ndarray | None = None  # (nb, 2, 3): F and M about G at t_n
        self._last_inertia: np.ndarray | None = None  # (nb, 6): f_I, m_I + ρ × f_I
        self.springs = list(springs)
        self.ties = list(ties)
        self.u = u
        surfaces = dict(surfaces or {})
        self.deformable = deformable if u is not None else None
        self.comm = u.function_space.mesh.comm if u is not None else (comm or MPI.COMM_WORLD)
        comm = self.comm
        self._check_topology(surfaces, fixed)
        self._index = {b.name: i for i, b in enumerate(self.bodies)}
        nb = len(self.bodies)

        # ---- FE layout: owned nodes free / tied / fixed --------------------------------------
        self._fe = u is not None
        self._tied_nodes: list[np.ndarray] = []  # local (owned + ghost) node indices per body
        self._tied_owned: list[np.ndarray] = []
        self._fixed_owned: dict[str, np.ndarray] = {}
        n_free_local = 0
        if self._fe:
            if residual is None:
                raise ValueError("RigidSystem: a deformable body (u) needs its residual form")
            V = u.function_space
            imap = V.dofmap.index_map
            if V.dofmap.index_map_bs != 3:
                raise ValueError("RigidSystem: u must be a 3D vector function")
            self._n_owned = imap.size_local
            n_all = self._n_owned + imap.num_ghosts
            self._X = V.tabulate_dof_coordinates()[:n_all]

            def nodes_of(surface: str) -> np.ndarray:
                tags, tag = surfaces[surface]
                dofs = dolfinx.fem.locate_dofs_topological(V, tags.dim, tags.find(tag))
                return owned_flags(imap, dofs, comm)

            taken = np.zeros(n_all, dtype=bool)
            fixed_all = np.zeros(n_all, dtype=bool)
            for surface in fixed:
                flags = nodes_of(surface)
                self._fixed_owned[surface] = np.flatnonzero(flags[: self._n_owned])
                fixed_all |= flags
            self._tie_flags = np.full(n_all, -1, dtype=np.int64)
            for b in range(nb):
                flags = np.zeros(n_all, dtype=bool)
                for tie in self.ties:
                    if tie.body == self.bodies[b].name:
                        flags |= nodes_of(tie.surface)
                both = comm.allreduce(int(np.count_nonzero(flags & fixed_all)), op=MPI.SUM)
                twice = comm.allreduce(int(np.count_nonzero(flags & taken)), op=MPI.SUM)
                if both or twice:
                    raise ValueError(
                        f"rigid body '{self.bodies[b].name}': {both} tied node(s) also fixed, "
                        f"{twice} tied to another body"
                    )
                taken |= flags
                self._tie_flags[flags] = b
                self._tied_nodes.append(np.flatnonzero(flags))
                self._tied_owned.append(np.flatnonzero(flags[: self._n_owned]))
            self._fixed_all = fixed_all
            free = ~(taken | fixed_all)[: self._n_owned]
            self._free_nodes = np.flatnonzero(free)
            n_free_local = 3 * len(self._free_nodes)
            fco = form_compiler_params or {}
            if jacobian is None:
                jacobian = ufl.derivative(residual, u, ufl.TrialFunction(V))
            self._F_form = dolfinx.fem.form(residual, form_compiler_params=fco)
            self._J_form = dolfinx.fem.form(jacobian, form_compiler_params=fco)
            self._F = fem_petsc.create_vector(self._F_form)
            self._K = fem_petsc.create_matrix(self._J_form)
            self._row0 = imap.local_range[0] * 3
            self._n_rows_global = imap.size_global * 3

        # ---- reduced layout: [free DOFs of each rank] + 6 per body on rank 0 -----------------
        self._n_free_local = n_free_local
        n_local = n_free_local + (6 * nb if comm.rank == 0 else 0)
        self._n_local = n_local
        self._start = comm.exscan(n_local) or 0
        self._rigid_start = comm.bcast(self._start + n_free_local, root=0)
        self._n_global = comm.allreduce(n_local, op=MPI.SUM)
        self._R0 = [b.rotation.copy() for b in self.bodies]
        self._phi = np.zeros((nb, 3))

        self._ends = [self._resolve_end(sp, i) for sp in self.springs for i in (0, 1)]

        self._x = PETSc.Vec().createMPI((n_local, self._n_global), comm=comm)
        self._r = self._x.duplicate()
        if self._fe:
            self._P = self._create_prolongation()
        self._J = self._create_jacobian()

        self.stats = RigidSolveStats()
        self.prefix = unique_prefix(name)
        # Rotating a tied face by a finite angle makes the first Newton iterate of a nearly
        # incompressible body (linearised rotation of the free nodes) far worse than the start:
        # no divergence test on the residual growth (max_it still bounds the solve).
        opts = default_snes_options() | {"snes_divergence_tolerance": -1.0} | dict(options or {})
        self.snes = PETSc.SNES().create(comm)
        self.snes.setOptionsPrefix(self.prefix)
        self.snes.setFunction(self._residual, self._r)
        self.snes.setJacobian(self._jacobian, self._J, self._J)
        set_from_options(self.snes, opts)
        self.snes.setConvergenceHistory(length=200, reset=True)
        self._linesearch = str(opts["snes_linesearch_type"])

    @property
    def linesearch(self) -> str:
        """The SNES line search type (``basic``, ``l2``, ``bt``, ``cp``)."""
        return self._linesearch

    @linesearch.setter
    def linesearch(self, kind: str) -> None:
        set_from_options(self.snes, {"snes_linesearch_type": kind}, ksp=False)
        self._linesearch = kind

    @property
    def _inertial(self) -> list[int]:
        """Indices of the bodies integrated in time (with a mass, not prescribed; dynamic)."""
        if not self.dynamic:
            return []
        return [i for i, b in enumerate(self.bodies) if b.mass is not None and not b.prescribed]

    # ---- checks ----------------------------------------------------------------------------
    def _check_topology(self, surfaces: dict, fixed: Sequence[str]) -> None:
        names = [b.name for b in self.bodies]
        if len(set(names)) != len(names) or GROUND in names:
            raise ValueError(f"rigid body names must be unique and not '{GROUND}': {names}")
        for surface in list(fixed) + [t.surface for t in self.ties]:
            if surface not in surfaces:
                raise ValueError(
                    f"surface '{surface}' does not exist (known: {', '.join(surfaces) or 'none'})"
                )
            tags, tag = surfaces[surface]
            count = self.comm.allreduce(len(tags.find(tag)), op=MPI.SUM)
            if count == 0:
                raise ValueError(f"surface '{surface}' (tag {tag}) has no facets")
        for tie in self.ties:
            if tie.body not in names:
                raise ValueError(
                    f"tie of surface '{tie.surface}': unknown rigid body '{tie.body}' "
                    f"(known: {', '.join(names) or 'none'})"
                )
        known = names + [GROUND] + ([self.deformable] if self.deformable else [])
        for s in self.springs:
            for end in (s.body_a, s.body_b):
                if end not in known:
                    raise ValueError(
                        f"spring '{s.name}': unknown body '{end}' (known: {', '.join(known)})"
                    )
        held = {t.body for t in self.ties}
        held |= {s.body_a for s in self.springs} | {s.body_b for s in self.springs}
        for b in self.bodies:
            if self.dynamic and b.mass is not None:
                continue
            if not b.prescribed and b.name not in held:
                why = (
                    "and has no mass: a dynamic scene cannot integrate it"
                    if self.dynamic
                    else "a static scene cannot balance its loads"
                )
                raise ValueError(
                    f"rigid body '{b.name}' is held by nothing (no tie, no spring, not "
                    f"prescribed): {why}"
                )

    def _resolve_end(self, spring: Spring, which: int) -> tuple:
        """One spring end as ``(kind, body index, reference point, owner, local node, col0)``.

        kind is "ground", "rigid" or "node" (a free FE node: owner rank, its local index there
        and the global reduced index of its x DOF). Collective.
        """
        body = (spring.body_a, spring.body_b)[which]
        point = np.asarray((spring.point_a, spring.point_b)[which], dtype=float)
        if body == GROUND:
            return ("ground", -1, point, -1, -1, -1)
        if body != self.deformable:
            return ("rigid", self._index[body], point, -1, -1, -1)
        comm = self.comm
        own = self._X[: self._n_owned]
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
            X = self._X[k].copy()
            if self._fixed_all[k]:
                info = ("ground", -1, X, -1, -1, -1)
            elif self._tie_flags[k] >= 0:
                info = ("rigid", int(self._tie_flags[k]), X, -1, -1, -1)
            else:
                pos = int(np.searchsorted(self._free_nodes, k))
                info = ("node", -1, X, owner, k, self._start + 3 * pos)
        return comm.bcast(info, root=owner)

    def _end_states(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """(current position m, lever ρ = R(P - X_ref) m) of every spring end (collective)."""
        node_u = np.zeros((len(self._ends), 3))
        for i, (kind, _, _, owner, k, _) in enumerate(self._ends):
            if kind == "node" and self.comm.rank == owner:
                node_u[i] = self.u.x.array.reshape(-1, 3)[k]
        if any(e[0] == "node" for e in self._ends):
            node_u = self.comm.allreduce(node_u, op=MPI.SUM)
        states = []
        for i, (kind, b, point, *_) in enumerate(self._ends):
            if kind == "rigid":
                body = self.bodies[b]
                lever = body.rotation @ (point - body.reference_point)
                states.append((body.position(point), lever))
            elif kind == "node":
                states.append((point + node_u[i], np.zeros(3)))
            else:
                states.append((point, np.zeros(3)))
        return states

    # ---- PETSc objects ---------------------------------------------------------------------
    def _rigid_cols(self, b: int) -> np.ndarray:
        return self._rigid_start + 6 * b + np.arange(6, dtype=PETSc.IntType)

    def _create_prolongation(self) -> PETSc.Mat:
        comm = self.comm
        n_rows = 3 * self._n_owned
        d_nnz = np.zeros(n_rows, dtype=PETSc.IntType)
        o_nnz = np.zeros(n_rows, dtype=PETSc.IntType)
        free_rows = (3 * self._free_nodes[:, None] + np.arange(3)).ravel()
        d_nnz[free_rows] = 1
        for owned in self._tied_owned:
            rows = (3 * owned[:, None] + np.arange(3)).ravel()
            (d_nnz if comm.rank == 0 else o_nnz)[rows] = 6
        P = PETSc.Mat().createAIJ(
            ((n_rows, self._n_rows_global), (self._n_local, self._n_global)), comm=comm
        )
        P.setPreallocationNNZ((d_nnz, o_nnz))
        P.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, True)
        for k, row in enumerate(free_rows):
            P.setValue(self._row0 + row, self._start + k, 1.0)
        self._fill_prolongation(P)
        return P

    def _fill_prolongation(self, P: PETSc.Mat) -> None:
        """Tied rows of P at the current rotations: [I, -hat(r_i) J_l(φ)]."""
        for b, owned in enumerate(self._tied_owned):
            if len(owned) == 0:
                continue
            cols = self._rigid_cols(b)
            body = self.bodies[b]
            if self.linear_ties:
                jl, r = np.eye(3), self._X[owned] - body.reference_point
            else:
                jl = _left_jacobian(self._phi[b])
                r = (self._X[owned] - body.reference_point) @ body.rotation.T
            # every tied row has the body's 6 columns: one dense (3 n) x 6 block, one call
            # (a call per node was two thirds of part 1's reduction time, measured at coarse)
            block = np.empty((len(owned), 3, 6))
            block[:, :, :3] = np.eye(3)
            block[:, :, 3:] = -hats(r) @ jl
            rows = (self._row0 + 3 * np.asarray(owned)[:, None] + np.arange(3)).ravel()
            P.setValues(rows.astype(PETSc.IntType), cols, block.reshape(-1, 6))
        P.assemble()

    def _create_jacobian(self) -> PETSc.Mat:
        comm, nb = self.comm, len(self.bodies)
        rigid = np.arange(self._rigid_start, self._rigid_start + 6 * nb, dtype=PETSc.IntType)
        if self._fe:
            self._update_state(self._x_from_state())
            self._assemble_K()
            self._C = self._K.PtAP(self._P)
            J = self._C.duplicate(copy=True)
            J.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, False)
        else:
            J = PETSc.Mat().createAIJ(((self._n_local, self._n_global),) * 2, comm=comm)
            J.setPreallocationNNZ((6 * nb, 0))
        if comm.rank == 0 and nb:
            J.setValues(rigid, rigid, np.zeros((6 * nb, 6 * nb)), addv=PETSc.InsertMode.ADD)
        if any(e[0] == "node" for e in self._ends):
            self._rigid_terms(with_tangent=True)  # the blocks' positions
            self._node_tan = [(i, k, 0.0 * block) for i, k, block in self._node_tan]
            self._add_node_blocks(J)
        J.assemble()
        J.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, True)
        return J

    # ---- state <-> reduced vector -----------------------------------------------------------
    def _x_from_state(self, targets: bool = True) -> PETSc.Vec:
        """Reduced vector of the current state (φ = 0, or the prescribed increment).

        During a dynamic step the inertial bodies that carry no tied surface start from the
        predictor θ = h Ω_n, x_G = x_n + h v_n + h² F_n/(2m); a body with tied nodes starts
        from the state at t_n (moving its tied nodes alone would distort the elements next to
        them: it made Newton diverge in a tested spinning case, while starting from t_n took
        4-5 iterations). ``targets=False``: the current state only.
        """
        tied = {t.body for t in self.ties}
        x = self._x
        arr = x.array
        if self._fe:
            arr[: self._n_free_local] = self.u.x.array.reshape(-1, 3)[self._free_nodes].ravel()
        if self.comm.rank == 0:
            for b, body in enumerate(self.bodies):
                t, phi = body.translation, np.zeros(3)
                if self.linear_ties:
                    phi = self._phi[b].copy()  # the total rotation vector (R0 = I)
                if targets and body.prescribed and body._target is not None:
                    t = body._target[0]
                    phi = log_so3(body._target[1] @ self._R0[b].T)
                elif (
                    targets
                    and self._dt is not None
                    and b in self._inertial
                    and body.name not in tied
                ):
                    h = self._dt
                    xg, v, R, w, _ = self._start_n[b]
                    phi = R @ (h * w)
                    R1 = exp_so3(phi) @ R
                    xg1 = xg + h * v + 0.5 * h * h * self._loads_n[b, 0] / body.mass
                    t = xg1 - body.reference_point - R1 @ (body.centre - body.reference_point)
                k = self._n_free_local + 6 * b
                arr[k : k + 3], arr[k + 3 : k + 6] = t, phi
        return x

    def _update_state(self, x: PETSc.Vec) -> None:
        """Bodies and the FE displacement from the reduced vector ``x`` (collective)."""
        arr = x.array_r
        nb = len(self.bodies)
        rigid = arr[self._n_free_local :].copy() if self.comm.rank == 0 else None
        rigid = self.comm.bcast(rigid, root=0).reshape(nb, 6) if nb else np.zeros((0, 6))
        for b, body in enumerate(self.bodies):
            body.translation = rigid[b, :3].copy()
            self._phi[b] = rigid[b, 3:]
            body.rotation = exp_so3(self._phi[b]) @ self._R0[b]
        if self._fe:
            u = self.u.x.array.reshape(-1, 3)
            u[self._free_nodes] = arr[: self._n_free_local].reshape(-1, 3)
            u[self._fixed_all] = 0.0
            for b, nodes in enumerate(self._tied_nodes):
                body = self.bodies[b]
                d = self._X[nodes] - body.reference_point
                if self.linear_ties:
                    u[nodes] = body.translation + np.cross(self._phi[b], d)
                else:
                    u[nodes] = body.translation + d @ body.rotation.T - d
            self.u.x.scatter_forward()

    # ---- assembly ----------------------------------------------------------------------------
    def _assemble_F(self) -> None:
        with self._F.localForm() as loc:
            loc.set(0.0)
        fem_petsc.assemble_vector(self._F, self._F_form)
        self._F.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        if self.contact is not None:
            self.contact.add_residual(self._F)
            self._F.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)

    def _assemble_K(self) -> None:
        self._K.zeroEntries()
        fem_petsc.assemble_matrix(self._K, self._J_form)
        self._K.assemble()

    def _tie_loads(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per body: Σ f_i (N), Σ r_i × f_i (N·m) and G = Σ hat(f_i) hat(r_i) (collective)."""
        nb = len(self.bodies)
        local = np.zeros((nb, 15))
        if self._fe:
            f_all = self._F.array_r.reshape(-1, 3)
            for b, owned in enumerate(self._tied_owned):
                body = self.bodies[b]
                f = f_all[owned]
                r = (self._X[owned] - body.reference_point) @ body.rotation.T
                G = np.einsum("nij,njk->ik", hats(f), hats(r))
                local[b] = np.r_[f.sum(axis=0), np.cross(r, f).sum(axis=0), G.ravel()]
        total = self.comm.allreduce(local, op=MPI.SUM)
        return total[:, :3], total[:, 3:6], total[:, 6:].reshape(nb, 3, 3)

    def _spring_terms(self) -> tuple[np.ndarray, np.ndarray, list, list]:
        """Springs' residual and tangent in spatial rigid coordinates (t, θ).

        Returns the rigid residual (6 per body), the rigid-rigid tangent (6nb × 6nb), the
        residual blocks of free FE nodes ``[(end index, vector3)]`` and the tangent blocks
        touching them ``[(row end, col end, block)]`` where an end is a spring-end index and a
        rigid side is still in (t, θ) coordinates.
        """
        nb = len(self.bodies)
        res = np.zeros(6 * nb)
        tan = np.zeros((6 * nb, 6 * nb))
        node_res, node_tan = [], []
        states = self._end_states()
        for j, spring in enumerate(self.springs):
            ia, ib = 2 * j, 2 * j + 1
            resp = spring_response(spring, states[ia][0], states[ib][0])
            g, kt = resp.gradient, resp.tangent
            maps = []  # (end index, kind, body, sign * B)
            for i, sign in ((ia, 1.0), (ib, -1.0)):
                kind, b = self._ends[i][0], self._ends[i][1]
                if kind == "rigid":
                    rho = states[i][1]
                    B = np.hstack([np.eye(3), -hat(rho)])
                    res[6 * b : 6 * b + 6] += sign * (B.T @ g)
                    tan[6 * b + 3 : 6 * b + 6, 6 * b + 3 : 6 * b + 6] += sign * hat(g) @ hat(rho)
                    maps.append((i, kind, b, sign * B))
                elif kind == "node":
                    node_res.append((i, sign * g))
                    maps.append((i, kind, -1, sign * np.eye(3)))
            for i, kind_i, b, Bi in maps:
                for k, kind_k, c, Bk in maps:
                    block = Bi.T @ kt @ Bk
                    if kind_i == "rigid" and kind_k == "rigid":
                        tan[6 * b : 6 * b + 6, 6 * c : 6 * c + 6] += block
                    else:
                        node_tan.append((i, k, block))
        return res, tan, node_res, node_tan

    def _rigid_terms(self, with_tangent: bool) -> tuple[np.ndarray, np.ndarray]:
        """Reduced residual and tangent of springs, loads and the ties' rotation terms (φ).

        The tangent holds ``Tᵀ (K_springs + G_ties) T`` with ``T = diag(I, J_l(φ))`` and, on the
        (φ, φ) block, ``∂(J_l(φ)ᵀ m)/∂φ`` with m the body's whole spatial moment residual (ties,
        springs, loads), which makes it the exact derivative of the reduced residual.
        """
        nb = len(self.bodies)
        res, tan, self._node_res, self._node_tan = self._spring_terms()
        zeros = np.zeros((nb, 3))
        if with_tangent and not self.linear_ties:
            _, tie_m, G = self._tie_loads()
        else:
            tie_m, G = zeros, np.zeros((nb, 3, 3))
        T = np.zeros((6 * nb, 6 * nb))
        moments = np.zeros((nb, 3))
        inertia_tangents = {}
        for b, body in enumerate(self.bodies):
            res[6 * b : 6 * b + 3] -= body.force
            res[6 * b + 3 : 6 * b + 6] -= body.moment
            if self._dt is not None and b in self._inertial:
                r_inertia, inertia_tangents[b] = self._inertia_terms(b)
                res[6 * b : 6 * b + 6] += r_inertia
            moments[b] = res[6 * b + 3 : 6 * b + 6] + tie_m[b]
            tan[6 * b + 3 : 6 * b + 6, 6 * b + 3 : 6 * b + 6] += G[b]
            T[6 * b : 6 * b + 3, 6 * b : 6 * b + 3] = np.eye(3)
            T[6 * b + 3 : 6 * b + 6, 6 * b + 3 : 6 * b + 6] = (
                np.eye(3) if self.linear_ties else _left_jacobian(self._phi[b])
            )
        tan = T.T @ tan @ T
        self._T = T
        for b, D in inertia_tangents.items():
            # D is already a derivative with respect to (t, φ): only the rows are mapped.
            Tb = T[6 * b : 6 * b + 6, 6 * b : 6 * b + 6]
            tan[6 * b : 6 * b + 6, 6 * b : 6 * b + 6] += Tb.T @ D
        for b in range(0 if self.linear_ties else nb):
            # J_l(φ)ᵀ = J_r(φ): the derivative of the rotation rows' J_lᵀ factor.
            tan[6 * b + 3 : 6 * b + 6, 6 * b + 3 : 6 * b + 6] += _d_jr_times(
                self._phi[b], moments[b]
            )
        return T.T @ res, tan

    def _inertia_terms(self, b: int) -> tuple[np.ndarray, np.ndarray]:
        """Inertia rows of body ``b`` during a dynamic step and their derivative.

        Returns ``(f_I, m_I + ρ × f_I)`` (spatial rows, N and N·m about the reference point,
        see the module docstring) and its exact derivative with respect to (t, φ), (6, 6):
        with δθ = J_l(φ) δφ the spatial rotation increment, δρ = δθ × ρ, δθ_body = R_nᵀ δφ,

            ∂f_I/∂t = k I,   ∂f_I/∂φ = -k hat(ρ) J_l,                       k = 4m/h²
            ∂m_I/∂φ = (2/h)(-hat(R_{n+1} w) J_l + (2/h) R_{n+1} I_G R_nᵀ),    w = I_G (2θ/h - Ω_n)
            ∂(ρ × f_I)/∂(t, φ) = hat(ρ) ∂f_I - hat(f_I) ∂ρ,                 ∂ρ/∂φ = -hat(ρ) J_l.
        """
        body, h = self.bodies[b], self._dt
        xg_n, v_n, R_n, w_n, L_n = self._start_n[b]
        F_n, M_n = self._loads_n[b]
        R = body.rotation
        rho = R @ (body.centre - body.reference_point)
        xg = body.reference_point + body.translation + rho
        theta = R_n.T @ self._phi[b]
        k = 4.0 * body.mass / (h * h)
        f = k * (xg - xg_n - h * v_n) - F_n
        Rw = R @ (body.inertia @ ((2.0 / h) * theta - w_n))
        m = (2.0 / h) * (Rw - L_n) - M_n
        jl = _left_jacobian(self._phi[b])
        H = hat(rho)
        D = np.zeros((6, 6))
        D[:3, :3] = k * np.eye(3)
        D[:3, 3:] = -k * H @ jl
        D[3:, :3] = k * H
        D[3:, 3:] = (
            (2.0 / h) * (-hat(Rw) @ jl + (2.0 / h) * R @ body.inertia @ R_n.T)
            - k * H @ H @ jl
            + hat(f) @ H @ jl
        )
        return np.r_[f, m + np.cross(rho, f)], D

    def _end_dofs(self, i: int) -> tuple[np.ndarray, int, np.ndarray | None]:
        """Reduced indices of spring end ``i``, their owner rank, and a rigid end's (t, φ) map.

        The map is the (6, 6) block of T = diag(I, J_l(φ)); None for a node end.
        """
        kind, b, _, owner, _, col0 = self._ends[i]
        if kind == "node":
            return col0 + np.arange(3, dtype=PETSc.IntType), owner, None
        return self._rigid_cols(b), 0, self._T[6 * b : 6 * b + 6, 6 * b : 6 * b + 6]

    def _add_node_blocks(self, J: PETSc.Mat) -> None:
        """Add the spring tangent blocks touching free FE nodes (set by the rows' owner)."""
        for i, k, block in self._node_tan:
            rows, owner, Ti = self._end_dofs(i)
            cols, _, Tk = self._end_dofs(k)
            if self.comm.rank != owner:
                continue
            if Ti is not None:
                block = Ti.T @ block
            if Tk is not None:
                block = block @ Tk
            J.setValues(rows, cols, block.ravel(), addv=PETSc.InsertMode.ADD_VALUES)

    def _prescribed_rows(self) -> np.ndarray:
        rows = [self._rigid_cols(b) for b, body in enumerate(self.bodies) if body.prescribed]
        if self.comm.rank != 0 or not rows:
            return np.zeros(0, dtype=PETSc.IntType)
        return np.concatenate(rows)

    # ---- SNES callbacks -------------------------------------------------------------------
    def _residual(self, snes: PETSc.SNES, x: PETSc.Vec, r: PETSc.Vec) -> None:
        with _timed(self.stats, "residual_s"):
            self._residual_impl(x, r)

    def _residual_impl(self, x: PETSc.Vec, r: PETSc.Vec) -> None:
        self._update_state(x)
        if self._fe:
            self._assemble_F()
            self._fill_prolongation(self._P)
            self._P.multTranspose(self._F, r)
        else:
            r.set(0.0)
        res, _ = self._rigid_terms(with_tangent=False)
        # Every rank touches the array (PETSc bumps the vector's state, which must stay the same
        # on all ranks or cached norms differ and the ranks fall out of step).
        arr = r.array
        for i, vec in self._node_res:
            _, _, _, owner, _, col0 = self._ends[i]
            if self.comm.rank == owner:
                arr[col0 - self._start : col0 - self._start + 3] += vec
        if self.comm.rank == 0:
            arr[self._n_free_local :] += res
            for b, body in enumerate(self.bodies):
                if body.prescribed:
                    k = self._n_free_local + 6 * b
                    arr[k : k + 6] = 0.0

    def _jacobian(self, snes: PETSc.SNES, x: PETSc.Vec, J: PETSc.Mat, P: PETSc.Mat) -> None:
        with _timed(self.stats, "jacobian_s"):
            self._jacobian_impl(x, J)

    def _jacobian_impl(self, x: PETSc.Vec, J: PETSc.Mat) -> None:
        self._update_state(x)
        J.zeroEntries()
        if self._fe:
            with _timed(self.stats, "fe_assembly_s"):
                self._assemble_F()
                self._assemble_K()
            with _timed(self.stats, "reduction_s"):
                self._fill_prolongation(self._P)
                self._K.PtAP(self._P, self._C)
                J.axpy(1.0, self._C, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
            if self.contact is not None:
                from shoulder_fem.engine.contact import add_to_pattern

                Kc = self.contact.jacobian_matrix(self._K)
                with _timed(self.stats, "reduction_s"):
                    Cc = Kc.PtAP(self._P)
                    self._contact_keys = add_to_pattern(J, Cc, self._contact_keys, self.comm)
                Kc.destroy()
                Cc.destroy()
        _, tan = self._rigid_terms(with_tangent=True)
        if self.comm.rank == 0 and len(self.bodies):
            rigid = np.arange(
                self._rigid_start, self._rigid_start + 6 * len(self.bodies), dtype=PETSc.IntType
            )
            J.setValues(rigid, rigid, tan.ravel(), addv=PETSc.InsertMode.ADD_VALUES)
        self._add_node_blocks(J)
        J.assemble()
        J.zeroRowsColumns(self._prescribed_rows(), 1.0)
        self.stats.factorizations += 1

    # ---- public API ------------------------------------------------------------------------
    def solve(self, step: str = "") -> int:
        """Solve for the current loads and prescribed motions; return the Newton iterations.

        Static: no inertia, even in a dynamic system (whose bodies keep their velocities; the
        loads that the next :meth:`step` starts from are re-evaluated at the new state). On
        success the bodies' rotations are committed (``R₀ ← exp(hat φ) R₀``). On failure the
        state is left at the last iterate (use :meth:`snapshot` / :meth:`restore`).

        Raises:
            ConvergenceError: The SNES did not converge (names the step, reason, iterations).
        """
        self._dt = None
        self._loads_n = None
        self._last_inertia = None
        its, _ = self._run_snes(step)
        self._commit()
        return its

    def _run_snes(self, step: str) -> tuple[int, PETSc.Vec]:
        """Run the SNES from the current state (or predictor); leave the state at the solution."""
        x = self._x_from_state()
        self.snes.setConvergenceHistory(length=200, reset=True)
        petsc_error = None
        with _timed(self.stats, "snes_s"):
            try:
                self.snes.solve(None, x)
            except PETSc.Error as err:  # e.g. MUMPS on a matrix with NaN entries
                petsc_error = f"PETSc error {err.ierr} in the solve (a failed factorization)"
            except ArithmeticError as err:  # a diverged iterate, e.g. a rotation vector of 1e80
                petsc_error = f"{type(err).__name__} in the residual or Jacobian ({err})"
        reason = self.snes.getConvergedReason()
        its = self.snes.getIterationNumber()
        history = [float(v) for v in self.snes.getConvergenceHistory()[0]]
        self.stats.solves += 1
        self.stats.newton_iterations += its
        self.stats.linear_solves += its
        self.stats.history.append(its)
        self.stats.residual_histories.append(history)
        if petsc_error or reason <= 0 or not math.isfinite(self.snes.getFunctionNorm()):
            # A failed factorization must not be reused by the next solve (MUMPS then stops
            # with INFOG(1) = -3): the next solve factorizes afresh.
            self.snes.getKSP().getPC().reset()
            raise ConvergenceError(step, petsc_error or reason_name(reason), its, self.prefix)
        self._update_state(x)
        if self._fe:
            self._assemble_F()
        logger.debug("%s %s: %d Newton iterations %s", self.prefix, step, its, history)
        return its, x

    # ---- dynamics ----------------------------------------------------------------------------
    def start_dynamics(self, time: float | None = None) -> None:
        """Take the current state as the initial state of the time integration (collective).

        Records the loads of the current state (ties, springs, applied ``force``/``moment``)
        that the first :meth:`step` averages with those of its end. Called by :meth:`step`
        when needed; call it explicitly to restart at ``time`` (s) after changing the state
        (velocities, :meth:`move`). The FE part should be in equilibrium with the bodies.
        """
        if not self.dynamic:
            raise ValueError(f"{self.prefix}: start_dynamics needs RigidSystem(dynamic=True)")
        if time is not None:
            self.time = float(time)
        self._commit()
        if self._fe:
            # Tied nodes at the bodies' current motions (a move() is applied now).
            self._update_state(self._x_from_state(targets=False))
        self._loads_n = self._external_loads()
        self._last_inertia = None

    def _external_loads(self) -> np.ndarray:
        """Per body, the total external force F (N) and moment about G (N·m) (collective).

        External: ties (minus the FE residual at the tied nodes), springs and applied loads,
        at the current state (the FE residual is assembled here).
        """
        nb = len(self.bodies)
        if self._fe:
            self._assemble_F()
        tie_f, tie_m, _ = self._tie_loads()
        res, _, _, _ = self._spring_terms()
        out = np.zeros((nb, 2, 3))
        for b, body in enumerate(self.bodies):
            F = body.force - res[6 * b : 6 * b + 3] - tie_f[b]
            M_ref = body.moment - res[6 * b + 3 : 6 * b + 6] - tie_m[b]
            rho = body.rotation @ (body.centre - body.reference_point)
            out[b] = F, M_ref - np.cross(rho, F)
        return out

    def _begin_step(self, dt: float) -> None:
        """Arm the residual and tangent of a step of ``dt`` (s) from the current state."""
        h = float(dt)
        if not self.dynamic:
            raise ValueError(
                f"{self.prefix}: step() needs RigidSystem(dynamic=True); use solve() for statics"
            )
        if not (math.isfinite(h) and h > 0.0):
            raise ValueError(f"{self.prefix}: time step must be finite and > 0 s, got {dt}")
        if self._loads_n is None:
            self.start_dynamics()
        self._commit()
        self._start_n = []
        for body in self.bodies:
            R = body.rotation.copy()
            L = R @ (body.inertia @ body.omega) if body.mass is not None else np.zeros(3)
            self._start_n.append(
                (body.centre_position(), body.velocity.copy(), R, body.omega.copy(), L)
            )
        self._dt = h

    def step(self, dt: float, step: str = "") -> int:
        """Advance the system by one implicit step of ``dt`` (s); return the Newton iterations.

        Set the applied loads (``body.force``, ``body.moment``) and the prescribed motions
        (:meth:`RigidBody.prescribe`) of the step's end, t + dt, before calling. On success the
        bodies' motions, velocities (``velocity``, ``omega``) and the FE displacement are those
        of t + dt and :attr:`time` is advanced. Prescribed and massless bodies get the
        trapezoidal-rule velocities of their motion. On failure the state is left at the last
        iterate and the time is not advanced (use :meth:`snapshot` / :meth:`restore`).

        Raises:
            ValueError: Not a dynamic system, or a bad ``dt``.
            ConvergenceError: The SNES did not converge (names the step, reason, iterations).
        """
        self._begin_step(dt)
        h = self._dt
        try:
            its, _ = self._run_snes(step or f"t={self.time + h:.9g} s")
            inertia = np.zeros((len(self.bodies), 6))
            for b in self._inertial:
                inertia[b] = self._inertia_terms(b)[0]
        finally:
            self._dt = None
        for b, body in enumerate(self.bodies):
            xg_n, v_n, R_n, w_n, _ = self._start_n[b]
            theta = R_n.T @ self._phi[b]
            body.velocity = (2.0 / h) * (body.centre_position() - xg_n) - v_n
            body.omega = (2.0 / h) * theta - w_n
        self._commit()
        self._loads_n = self._external_loads()
        self._last_inertia = inertia
        self.time += h
        return its

    def energy(self) -> dict[str, float]:
        """Kinetic energy of the bodies with a mass and elastic energy of the springs (J)."""
        kinetic = sum(b.kinetic_energy() for b in self.bodies if b.mass is not None)
        springs = 0.0
        for spring, out in zip(self.springs, self.spring_forces().values(), strict=True):
            if out["tension"] != 0.0 or not spring.tension_only:
                springs += 0.5 * spring.stiffness * (out["length"] - spring.rest_length) ** 2
        return {"kinetic": float(kinetic), "springs": float(springs)}

    def reduced_vector(self) -> PETSc.Vec:
        """A new vector of the reduced layout holding the current state (φ = 0)."""
        return self._x_from_state().copy()

    def move(self, name: str, translation: np.ndarray, rotation: np.ndarray) -> None:
        """Set body ``name``'s motion now (m, rotation matrix): a predictor for the next solve.

        The tied nodes follow at the next solve; the free nodes keep ``u`` (set them too for a
        good start). In a dynamic system, call :meth:`start_dynamics` after moving bodies to
        take the new state as an initial state.
        """
        b = self._index[name]
        body = self.bodies[b]
        body.translation = np.asarray(translation, dtype=float).copy()
        body.rotation = np.asarray(rotation, dtype=float).copy()
        self._R0[b], self._phi[b] = body.rotation.copy(), 0.0
        self._last_inertia = None

    def _commit(self) -> None:
        if self.linear_ties:
            return  # φ is the total rotation vector, R0 stays the identity
        for b, body in enumerate(self.bodies):
            self._R0[b] = body.rotation.copy()
            self._phi[b] = 0.0

    def snapshot(self) -> tuple:
        """The state (FE displacement, body motions, dynamic state) for :meth:`restore`."""
        u = self.u.x.array.copy() if self._fe else None
        motions = [(b.translation.copy(), b.rotation.copy()) for b in self.bodies]
        dynamics = (
            [(b.velocity.copy(), b.omega.copy()) for b in self.bodies],
            None if self._loads_n is None else self._loads_n.copy(),
            None if self._last_inertia is None else self._last_inertia.copy(),
            self.time,
        )
        return u, motions, dynamics

    def restore(self, snapshot: tuple) -> None:
        """Put back a :meth:`snapshot`."""
        u, motions, *rest = snapshot
        if self._fe:
            self.u.x.array[:] = u
        for b, (body, (t, R)) in enumerate(zip(self.bodies, motions, strict=True)):
            body.translation, body.rotation = t.copy(), R.copy()
            self._R0[b], self._phi[b] = R.copy(), 0.0
        if rest:
            velocities, loads, inertia, self.time = rest[0]
            for body, (v, w) in zip(self.bodies, velocities, strict=True):
                body.velocity, body.omega = v.copy(), w.copy()
            self._loads_n = None if loads is None else loads.copy()
            self._last_inertia = None if inertia is None else inertia.copy()
        self._dt = None

    def balance(self, name: str) -> BodyBalance:
        """Forces and moments on body ``name`` at the current state (collective).

        Tie forces are those the deformable body exerts on the rigid body (minus the FE
        residual at its tied nodes); moments are about the body's current reference point.
        A prescribed body also receives the (unreported) reaction of its prescription.
        """
        b = self._index[name]
        body = self.bodies[b]
        if self._fe:
            self._assemble_F()
        tie_f, tie_m, _ = self._tie_loads()
        spring_f, spring_m = np.zeros(3), np.zeros(3)
        states = self._end_states()
        for j, spring in enumerate(self.springs):
            ia, ib = 2 * j, 2 * j + 1
            gradient = spring_response(spring, states[ia][0], states[ib][0]).gradient
            for i, sign in ((ia, -1.0), (ib, 1.0)):
                if self._ends[i][0] == "rigid" and self._ends[i][1] == b:
                    spring_f += sign * gradient
                    spring_m += np.cross(states[i][1], sign * gradient)
        inertia = np.zeros(6) if self._last_inertia is None else -self._last_inertia[b]
        return BodyBalance(
            -tie_f[b],
            -tie_m[b],
            spring_f,
            spring_m,
            body.force.copy(),
            body.moment.copy(),
            inertia[:3].copy(),
            inertia[3:].copy(),
        )

    def spring_forces(self) -> dict[str, dict[str, float]]:
        """Per spring: length (m), tension (N, positive when stretched) (collective)."""
        states = self._end_states()
        out = {}
        for j, spring in enumerate(self.springs):
            resp = spring_response(spring, states[2 * j][0], states[2 * j + 1][0])
            out[spring.name] = {"length": resp.length, "tension": resp.tension}
        return out

    def assembled_residual(self) -> PETSc.Vec:
        """The FE residual (N) at the current state, without conditions (collective; read only)."""
        self._assemble_F()
        return self._F

    def reaction(self, surface: str, point: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
        """Force (N) and moment about ``point`` (m, default origin, N·m) on fixed ``surface``."""
        point = np.zeros(3) if point is None else np.asarray(point, dtype=float)
        self._assemble_F()
        owned = self._fixed_owned[surface]
        f = self._F.array_r.reshape(-1, 3)[owned]
        x = self._X[owned] + self.u.x.array.reshape(-1, 3)[owned]
        local = np.r_[f.sum(axis=0), np.cross(x - point, f).sum(axis=0)]
        total = self.comm.allreduce(local, op=MPI.SUM)
        return total[:3], total[3:]

    def tied_positions(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """Reference and current positions (m) of the nodes tied to ``name``, on every rank."""
        owned = self._tied_owned[self._index[name]]
        X = self._X[owned]
        x = X + self.u.x.array.reshape(-1, 3)[owned]
        Xs = self.comm.allgather(X)
        xs = self.comm.allgather(x)
        return np.vstack(Xs), np.vstack(xs)

    def destroy(self) -> None:
        """Free the PETSc objects."""
        objs = [self.snes, self._J, self._x, self._r]
        if self._fe:
            objs += [self._P, self._C, self._K, self._F]
        for obj in objs:
            obj.destroy()
