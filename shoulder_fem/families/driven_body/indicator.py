"""How far the decoupling is from exact: the indicator of the terms step 1 neglects.

Owns :class:`DecouplingIndicator` (paper eqs. 11–12: the force and moment of the straining
motion against those of the rigid motion), :func:`spin_stiffness_ratio` (the centrifugal terms
the linear eq. (13) leaves out, against the elastic ones), and :class:`DecouplingRecord`, which
records both after each step of a driven body's decoupled run and warns once when the indicator
is no longer small.
"""

from __future__ import annotations

import logging

import dolfinx
import numpy as np
import ufl
from mpi4py import MPI
from petsc4py import PETSc

from shoulder_fem.engine.fem import constant
from shoulder_fem.engine.mass import MassProperties
from shoulder_fem.engine.newmark import NewmarkState
from shoulder_fem.families.driven_body.frame import FloatingFrame
from shoulder_fem.families.driven_body.model import DrivenBody
from shoulder_fem.forms import kinematics, materials
from shoulder_fem.io.results import Recorder

logger = logging.getLogger(__name__)

#: Above this value of the decoupling indicator a warning is logged and the run is marked
#: outside the method's validity.
INDICATOR_WARNING = 0.05
#: Above this spin-stiffness ratio (the centrifugal terms the linear eq. (13) leaves out,
#: against the elastic ones) the run is marked outside the method's validity: the neglected
#: terms are a tenth of those kept, an error of that order. Measured: spinning-bar by default
#: 0.017; spin-up-beam 1.58 (0.57 m of deflection, the README's failing case); spinning-bar at
#: 5e4 rad/s 466.
SPIN_STIFFNESS_LIMIT = 0.1


def spin_stiffness_ratio(recorder) -> float:
    """Largest Ω²∫ρ|ũ⊥|² / ∫σ:ε over the steps whose strain energy is ≥ 1 % of its maximum.

    Small: the centrifugal terms the paper's linear eq. (13) leaves out are negligible. Near or
    above 1: the spin reaches the deformation's own frequency and the variants part ways.
    """
    spin = np.asarray(recorder.series.get("spin_energy", {}).get("y", []), dtype=float)
    elastic = np.asarray(recorder.series.get("strain_energy", {}).get("y", []), dtype=float)
    if not len(elastic) or not np.isfinite(elastic).all() or elastic.max() <= 0.0:
        return 0.0
    keep = elastic >= 0.01 * elastic.max()
    return float(np.max(spin[keep] / elastic[keep]))


class DecouplingIndicator:
    """The terms step 1 of the decoupling neglects (paper eqs. 11–12), relative to those kept.

    Neglected, in the body frame: the force ∫ρ ṽ̇ + 2Ω × ∫ρ ṽ, and the moment about G
    ∫ρ GM × ṽ̇ + 2∫ρ GM × (Ω × ṽ) + ΔI Ω̇ + Ω × ΔI Ω with ΔI the first-order change of I_G due
    to ũ. Kept: m a_G and I_G Ω̇ + Ω × I_G Ω, measured by the scales m(|a_G| + r_g(|Ω̇| + |Ω|²))
    and ‖I_G‖(|Ω̇| + |Ω|²) (r_g the radius of gyration) so that a steady spin about a principal
    axis, whose kept moment vanishes, still has a finite reference; each scale is its largest
    value over the whole rigid motion (known from part 1 before part 2 starts), so the start
    from rest does not divide by ~0. The indicator is the larger of the two ratios
    (dimensionless); 0 for a body that never moves.

    All the integrals are linear in the fields: 12 vectors (∫ρ e_k·w and ∫ρ GM_i e_j·w) are
    assembled once and each evaluation is a few dot products.
    """

    def __init__(self, mesh, V, rho, gm, dx, mass, x_g, inertia):
        w = ufl.TestFunction(V)
        direction = constant(mesh, np.zeros(3))
        weight = constant(mesh, np.zeros(3))
        form = dolfinx.fem.form(rho * ufl.dot(weight, gm) * ufl.dot(direction, w) * dx)
        form_mass = dolfinx.fem.form(rho * ufl.dot(direction, w) * dx)
        self.comm = mesh.comm
        n_owned = V.dofmap.index_map.size_local * V.dofmap.index_map_bs
        self._n = n_owned
        eye = np.eye(3)

        def assemble(f) -> np.ndarray:
            vec = dolfinx.fem.petsc.assemble_vector(f)
            vec.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
            out = vec.array[:n_owned].copy()
            vec.destroy()
            return out

        self._m = []
        for k in range(3):
            direction.value[:] = eye[k]
            self._m.append(assemble(form_mass))
        self._t = [[None] * 3 for _ in range(3)]
        for i in range(3):
            weight.value[:] = eye[i]
            for j in range(3):
                direction.value[:] = eye[j]
                self._t[i][j] = assemble(form)
        self.mass = mass
        self.x_g = np.asarray(x_g)
        self.inertia = np.asarray(inertia)
        self.inertia_norm = float(np.linalg.norm(self.inertia, 2))
        self.r_g = float(np.sqrt(self.inertia_norm / mass))
        self._force_ref = 0.0
        self._moment_ref = 0.0

    def set_motion(self, omegas: np.ndarray, domegas: np.ndarray) -> None:
        """Reference scales from the whole rigid motion (part 1 is known before part 2).

        Args:
            omegas: body-frame angular velocities at the output times, shape (n, 3), rad/s.
            domegas: body-frame angular accelerations at the same times, rad/s².
        """
        spin = np.linalg.norm(domegas, axis=1) + np.linalg.norm(omegas, axis=1) ** 2
        a_g = np.cross(domegas, self.x_g) + np.cross(omegas, np.cross(omegas, self.x_g))
        self._force_ref = float(np.max(self.mass * (np.linalg.norm(a_g, axis=1) + self.r_g * spin)))
        self._moment_ref = float(np.max(self.inertia_norm * spin))

    def _first(self, field) -> np.ndarray:
        local = np.array([m @ field for m in self._m])
        return self.comm.allreduce(local, op=MPI.SUM)

    def _second(self, field) -> np.ndarray:
        local = np.array([[self._t[i][j] @ field for j in range(3)] for i in range(3)])
        return self.comm.allreduce(local, op=MPI.SUM)

    def evaluate(self, state, omega: np.ndarray, domega: np.ndarray) -> float:
        """The indicator for the state at the end of the last step (collective)."""
        n = self._n
        u, v, a = (f.x.array[:n] for f in (state.u_n, state.v_n, state.a_n))
        force = self._first(a) + 2.0 * np.cross(omega, self._first(v))
        ta, tv, tu = self._second(a), self._second(v), self._second(u)
        eps = np.array(
            [
                [[float((i - j) * (j - k) * (k - i) / 2) for k in range(3)] for j in range(3)]
                for i in range(3)
            ]
        )
        moment = np.einsum("kij,ij->k", eps, ta)  # ∫ρ GM × ṽ̇
        moment += 2.0 * (omega * np.trace(tv) - tv.T @ omega)  # 2∫ρ GM × (Ω × ṽ)
        delta_i = 2.0 * np.trace(tu) * np.eye(3) - (tu + tu.T)
        moment += delta_i @ domega + np.cross(omega, delta_i @ omega)
        if self._force_ref == 0.0 or self._moment_ref == 0.0:
            return 0.0
        return float(
            max(np.linalg.norm(force) / self._force_ref, np.linalg.norm(moment) / self._moment_ref)
        )


class DecouplingRecord:
    """Series of a driven body's decoupled run: the indicator and the spin-stiffness energies.

    What the linear part neglects of eq. (13) itself: the centrifugal terms on ũ against the
    elastic ones, Ω²∫ρ|ũ⊥|² / ∫σ(ũ):ε(ũ) — a Rayleigh-quotient estimate of (Ω/ω)² for the
    current deformation shape ω.

    Args:
        model: the driven body.
        recorder: the run's recorder.
        state: the Newmark state of the straining displacement ũ.
        material: the linear elastic law of eq. (13).
        frame: the floating frame (its Ω is that of the last step).
        props: the body's mass properties about G.
        dx: the volume measure of the method.
    """

    def __init__(
        self,
        model: DrivenBody,
        recorder: Recorder,
        state: NewmarkState,
        material: materials.LinearElastic,
        frame: FloatingFrame,
        props: MassProperties,
        dx: ufl.Measure,
    ):
        self.model, self.recorder, self.state = model, recorder, state
        mesh, rho, u, omega = model.mesh, model.density, state.u, frame.omega
        self.comm = mesh.comm
        self.indicator = DecouplingIndicator(
            mesh, u.function_space, rho, frame.gm, dx, props.mass, props.centre, props.inertia
        )
        self.indicator.set_motion(
            np.array([model.motion.omega_vector(t) for t in model.times]),
            np.array([model.motion.domega_vector(t) for t in model.times]),
        )
        self.spin_energy = dolfinx.fem.form(
            rho * ufl.dot(ufl.cross(omega, u), ufl.cross(omega, u)) * dx
        )
        self.strain_energy = dolfinx.fem.form(
            ufl.inner(material.stress(kinematics.linear_strain(u)), kinematics.linear_strain(u))
            * dx
        )
        self.warned = False

    def _total(self, form) -> float:
        return self.comm.allreduce(dolfinx.fem.assemble_scalar(form), op=MPI.SUM)

    def record(self, t: float) -> None:
        """Record the indicator and the two energies (J) at the end of the step at ``t`` (s)."""
        motion, recorder = self.model.motion, self.recorder
        value = self.indicator.evaluate(self.state, motion.omega_vector(t), motion.domega_vector(t))
        recorder.add_series_point("decoupling_indicator", t, value, "s", "1")
        recorder.add_series_point("spin_energy", t, self._total(self.spin_energy), "s", "J")
        recorder.add_series_point("strain_energy", t, self._total(self.strain_energy), "s", "J")
        if value > INDICATOR_WARNING and not self.warned:
            self.warned = True
            logger.warning(
                "t = %.4g s: decoupling indicator %.3g > %.3g: the straining motion's share of "
                "the momentum balance is no longer small; compare with the coupled method",
                t,
                value,
                INDICATOR_WARNING,
            )

    def finish(self) -> None:
        """Probes: the largest indicator and spin-stiffness ratio; the run's validity.

        ``summary.json`` gets ``"validity"``: ``"inside"``, or ``"outside"`` with
        ``"validity_reason"`` (and a warning) when either exceeds its bound.
        """
        recorder = self.recorder
        series = recorder.series.get("decoupling_indicator", {}).get("y", [0.0])
        indicator, ratio = float(max(series)), spin_stiffness_ratio(recorder)
        recorder.set_probe("max_decoupling_indicator", indicator, "1")
        recorder.set_probe("max_spin_stiffness_ratio", ratio, "1")
        reasons = []
        if indicator > INDICATOR_WARNING:
            reasons.append(
                f"decoupling indicator {indicator:.3g} > {INDICATOR_WARNING:g} (the straining "
                "motion's share of the momentum balance is not small)"
            )
        if ratio > SPIN_STIFFNESS_LIMIT:
            reasons.append(
                f"spin-stiffness ratio {ratio:.3g} > {SPIN_STIFFNESS_LIMIT:g} (the centrifugal "
                "terms the linear eq. (13) leaves out are not small against the elastic ones)"
            )
        recorder.extra("validity", "outside" if reasons else "inside")
        if reasons:
            reason = "; ".join(reasons) + ": compare with the coupled method"
            recorder.extra("validity_reason", reason)
            logger.warning("outside the decoupled method's validity: %s", reason)
