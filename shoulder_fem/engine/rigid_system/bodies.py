"""The rigid bodies of a :class:`RigidSystem`, their ties to surfaces and the forces on them.

Plain data with validation (mass and inertia checked when set, before any solve); the system
updates the bodies' states in place.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from shoulder_fem.engine.mass import MassProperties
from shoulder_fem.engine.rigid import RigidState

__all__ = ["BodyBalance", "RigidBody", "Tie"]


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
            :mod:`shoulder_fem.engine.rigid` (state, dynamics).

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
        """The body's dynamic state as a :class:`~shoulder_fem.engine.rigid.RigidState` (at G)."""
        return RigidState(time, self.centre_position(), self.velocity, self.rotation, self.omega)

    def prescribe(self, translation: np.ndarray, rotation: np.ndarray) -> None:
        """Set the motion of a prescribed body for the next solve (m, rotation matrix)."""
        if not self.prescribed:
            raise ValueError(f"rigid body '{self.name}' is not prescribed")
        self._target = (np.asarray(translation, float).copy(), np.asarray(rotation, float).copy())

    @property
    def target(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The motion set by :meth:`prescribe` for the next solve (m, rotation), or ``None``."""
        return self._target

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
