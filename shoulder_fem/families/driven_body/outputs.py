"""What both driven-body methods report, measured in the body (rotating) frame.

Owns :class:`BodyOutputs` (tip deflection, axial-stress profile, stress fields) built from two
UFL expressions each method supplies in the body frame — the straining displacement ũ and the
stress tensor — the clamp's consistent reaction (:func:`boundary_reaction`), and the probes of
the last completed step (:func:`finish_probes`). Measuring both methods one way keeps their
comparison like for like.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import dolfinx
import numpy as np
import ufl
from mpi4py import MPI
from petsc4py import PETSc

from shoulder_fem.families.driven_body.model import DrivenBody, quadrature
from shoulder_fem.forms import materials
from shoulder_fem.meshes.bar import TIP

if TYPE_CHECKING:
    from shoulder_fem.io.results import Recorder


@dataclass
class LastStep:
    """The last completed step, shared by the time loop and a method's ``advance``.

    Attributes:
        t: its time (s).
        step: its index (0: the initial state).
        reaction: force the clamp exerts on the body (body frame, N).
        moment: moment of that force about the origin (body frame, N·m).
    """

    t: float = 0.0
    step: int = 0
    reaction: np.ndarray = field(default_factory=lambda: np.zeros(3))
    moment: np.ndarray = field(default_factory=lambda: np.zeros(3))


class BodyOutputs:
    """Measures a run in the body frame; every call is collective.

    Args:
        model: the model.
        u_body: UFL expression of the straining displacement ũ (body frame, m).
        stress_body: UFL expression of the stress tensor in body-frame components (Pa).
    """

    def __init__(self, model: DrivenBody, u_body, stress_body):
        self.model = model
        mesh = model.mesh
        self.comm = mesh.comm
        params = quadrature(model)
        ds = ufl.Measure("ds", domain=mesh, subdomain_data=model.facet_tags)
        ey = ufl.as_vector((0.0, 1.0, 0.0))
        self._tip = dolfinx.fem.form(ufl.dot(u_body, ey) * ds(TIP.id), form_compiler_params=params)
        # Section-averaged σ_xx at each element layer's mid-plane: Gauss points on the
        # reference mid-plane ξ0 = 1/2 of every cell (the structured bar mesh gives every cell
        # of a layer the same section, so cells weigh alike).
        g, gw = np.polynomial.legendre.leggauss(model.degree + 1)
        g, gw = (g + 1) / 2, gw / 2
        self._points = np.array([[0.5, a, b] for a in g for b in g])
        self._weights = np.array([wa * wb for wa in gw for wb in gw])
        self._sxx_section = dolfinx.fem.Expression(stress_body[0, 0], self._points)
        n_owned = mesh.topology.index_map(3).size_local
        self._cells = np.arange(n_owned, dtype=np.int32)
        mid = dolfinx.mesh.compute_midpoints(mesh, 3, self._cells)
        edges = np.linspace(model.inner_radius, model.outer_radius, model.n_axial + 1)
        self.layer_edges = edges
        self._layer = np.clip(np.searchsorted(edges, mid[:, 0]) - 1, 0, model.n_axial - 1)
        self._layer_cells = self.comm.allreduce(
            np.bincount(self._layer, minlength=model.n_axial), op=MPI.SUM
        )
        Q0 = dolfinx.fem.FunctionSpace(mesh, ("DG", 0))
        # Fields for ParaView: axial and von Mises stress per cell (DG0, midpoint values).
        self.axial_stress = dolfinx.fem.Function(Q0, name="axial_stress")
        self.von_mises = dolfinx.fem.Function(Q0, name="von_mises")
        s = stress_body
        points = Q0.element.interpolation_points()
        self._sxx_expr = dolfinx.fem.Expression(s[0, 0], points)
        self._vm_expr = dolfinx.fem.Expression(materials.von_mises(s), points)

    def tip_deflection(self) -> float:
        """In-plane transverse (y) tip displacement in the rotating frame, tip-face mean (m)."""
        value = dolfinx.fem.assemble_scalar(self._tip)
        return self.comm.allreduce(value, op=MPI.SUM) / self.model.area

    def axial_stress_profile(self) -> tuple[np.ndarray, np.ndarray]:
        """Section-averaged axial stress at each layer's mid-plane: (radius m, σ_xx Pa)."""
        values = self._sxx_section.eval(self._cells).reshape(len(self._cells), -1)
        cell_means = values @ self._weights
        sums = self.comm.allreduce(
            np.bincount(self._layer, weights=cell_means, minlength=self.model.n_axial),
            op=MPI.SUM,
        )
        centres = 0.5 * (self.layer_edges[:-1] + self.layer_edges[1:])
        return centres, sums / self._layer_cells

    def max_von_mises(self) -> float:
        """Largest cell value of the von Mises stress from the last :meth:`update_fields` (Pa)."""
        n_owned = self.model.mesh.topology.index_map(3).size_local
        local = float(np.max(self.von_mises.x.array[:n_owned])) if n_owned else 0.0
        return self.comm.allreduce(local, op=MPI.MAX)

    def update_fields(self) -> list[dolfinx.fem.Function]:
        """Evaluate the stress fields (collective); returns them for writing."""
        self.axial_stress.interpolate(self._sxx_expr)
        self.von_mises.interpolate(self._vm_expr)
        return [self.axial_stress, self.von_mises]


def boundary_reaction(
    residual: dolfinx.fem.FormMetaClass,
    dofs: np.ndarray,
    comm,
    coords: np.ndarray,
    rotation: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Force (N) and moment about the origin (N·m) the supports exert on ``dofs``, body frame.

    With R = P_int + P_acc − P_ext assembled without boundary conditions, the components at the
    clamped DOFs are the forces the clamp must apply to the body (variationally consistent
    reactions). ``coords`` are the DOFs' reference (body-frame) positions; the clamped nodes sit
    there in the body frame. ``rotation`` (body → inertial) turns inertial-frame residuals into
    body-frame forces.
    """
    vec = dolfinx.fem.petsc.assemble_vector(residual)
    vec.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    bs = 3
    n_owned = vec.getLocalSize() // bs
    owned = dofs[dofs < n_owned]
    forces = vec.array.reshape(-1, bs)[owned]
    vec.destroy()
    if rotation is not None:
        forces = forces @ rotation  # rows fᵀR = (Rᵀf)ᵀ
    local = np.concatenate([forces.sum(axis=0), np.cross(coords[owned], forces).sum(axis=0)])
    total = comm.allreduce(local, op=MPI.SUM)
    return total[:3], total[3:]


def finish_probes(
    model: DrivenBody, recorder: Recorder, outputs: BodyOutputs, last: LastStep
) -> None:
    """Probes of the last completed step (also after a failed step: the completed steps stand).

    ``root_axial_stress`` is the clamp's consistent axial reaction divided by the section area
    (Pa); ``axial_stress_profile`` the section-averaged σ_xx at each layer's mid-plane.
    """
    centres, profile = outputs.axial_stress_profile()
    recorder.set_series("axial_stress_profile", centres, profile, "m", "Pa")
    if model.spin_axis == "transverse":
        recorder.set_series(
            "axial_stress_profile_analytic",
            centres,
            model.analytic_axial_stress(centres, model.motion.rate(last.t)),
            "m",
            "Pa",
        )
    recorder.set_probe("root_axial_stress", -last.reaction[0] / model.area, "Pa")
    # The moment the hub applies to the body (about the origin, body frame) and its component
    # along the spin axis: the driving torque.
    recorder.set_probe("root_moment", last.moment, "N*m")
    recorder.set_probe("root_torque", float(last.moment @ model.axis), "N*m")
    vm = recorder.series.get("max_von_mises", {}).get("y", [])
    recorder.set_probe("max_von_mises", float(max(vm)) if vm else 0.0, "Pa")
    recorder.set_probe("tip_deflection_final", outputs.tip_deflection(), "m")
    recorder.set_probe("final_time", last.t, "s")
    series = np.asarray(recorder.series["tip_deflection"]["y"])
    peak = int(np.argmax(np.abs(series)))
    recorder.set_probe("peak_tip_deflection", float(series[peak]), "m")
    recorder.set_probe("peak_time", float(recorder.series["tip_deflection"]["x"][peak]), "s")
    torque = np.asarray(recorder.series["root_torque"]["y"])
    recorder.set_probe("peak_root_torque", float(torque[np.argmax(np.abs(torque))]), "N*m")
    if model.spin_axis == "transverse":
        recorder.set_probe(
            "root_axial_stress_analytic",
            float(model.analytic_axial_stress(model.inner_radius, model.motion.rate(last.t))),
            "Pa",
        )
    else:
        # Spin about the bar's own axis: the hub's torque drives the bar's polar inertia,
        # ρ L a⁴/6 for a square section; its quasi-static peak at the largest Ω̇.
        peak_rate_dot = float(np.max(np.abs(model.motion.acceleration(model.times))))
        length = model.outer_radius - model.inner_radius
        recorder.set_probe(
            "peak_root_torque_analytic",
            model.density * length * model.side**4 / 6 * peak_rate_dot,
            "N*m",
        )
