"""Method ``decoupled``, part 1 and the transfer to part 2.

Part 1: the bones rigid (six DOFs each), the cartilages and muscles deformable, the same
contact and springs as the coupled method, driven by :mod:`.stepping`. At each output angle it
records the nodal forces that the glenoid cartilage and the supraspinatus and infraspinatus
apply to the scapula, and the scapula's rigid motion (:class:`Transfer`); part 2
(:mod:`.part2`) loads the elastic scapula with them.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from shoulder_fem.engine.rigid_system import RigidBody, RigidSystem, Tie
from shoulder_fem.engine.springs import GROUND, Spring
from shoulder_fem.families.base import RunContext
from shoulder_fem.families.shoulder import mesh_store
from shoulder_fem.families.shoulder.correction import NodalValues, Offsets, adopt, correct_part1
from shoulder_fem.families.shoulder.geometry import patch_centroid, surface_centroid
from shoulder_fem.families.shoulder.humerus import HumerusRecorder, humerus_offsets
from shoulder_fem.families.shoulder.interactions import (
    joint_contact,
    soft_tissue_residual,
    spring_layout,
    surfaces,
    uncondensed,
)
from shoulder_fem.families.shoulder.load_map import load_map, surface_triangles
from shoulder_fem.families.shoulder.measures import Probe
from shoulder_fem.families.shoulder.model import (
    ShoulderModel,
    ShoulderParameters,
    displacement,
    scapula_at,
)
from shoulder_fem.families.shoulder.outputs import UNCORRECTED, save_npz, save_results, unknowns
from shoulder_fem.families.shoulder.part2 import SurfaceForces, run_part2
from shoulder_fem.families.shoulder.reuse import load_part1
from shoulder_fem.families.shoulder.stepping import SNES_OPTIONS, Stepping, run_steps
from shoulder_fem.families.shoulder.trial import SoftTissueCheck, trial_i1bar_max
from shoulder_fem.families.shoulder.twist import rigid_twist
from shoulder_fem.io.resources import release_memory
from shoulder_fem.io.results import Recorder
from shoulder_fem.meshes import shoulder as S

__all__ = ["HUMERUS_TIES", "SCAPULA_LOAD_SURFACES", "Transfer", "run_decoupled", "run_part1"]

#: The scapula's surfaces loaded by part 1's soft tissues: their forces go to part 2 (with the
#: master of the muscle-scapula contact, :data:`meshes.shoulder.SCAPULA_CONTACT_SURFACE`).
SCAPULA_LOAD_SURFACES = ("glenoid_cartilage_bone", "supraspinatus_origin", "infraspinatus_origin")
#: The soft tissues' surfaces on the humerus, carried by the rigid humerus in part 1.
HUMERUS_TIES = (
    "humeral_cartilage_bone",
    "subscapularis_insertion",
    "supraspinatus_insertion",
    "infraspinatus_insertion",
)


def run_decoupled(model: ShoulderModel, run: RunContext) -> None:
    """Method #2: part 1 (rigid bones), then part 2 (scapula, linear, floating frame).

    With ``run.part1_from`` part 1 is the recorded one of that run (:mod:`.reuse`).
    """
    layout = spring_layout(model.params)
    if run.part1_from is not None:
        data, fields = load_part1(model, run.part1_from)
        transfer = Transfer(**fields)
        run.recorder.extra("part1_from", str(run.part1_from))
    elif model.params.compliant_part1:
        data, transfer = _compliant_part1(model, run, layout)
    else:
        data, transfer = run_part1(model, run, layout)
    if "rigid-bone" in model.meshes:  # part 1 ran here: keep its scapula for later part 2s
        mesh_store.save(model.meshes["scapula"], run.fields.parent)
    # part 2 holds the scapula alone: part 1's mesh, spaces and forms go before it starts
    model.meshes.pop("rigid-bone", None)
    release_memory()
    level2 = model.params.part2_level or model.level
    if level2 != model.level:
        with run.monitor.stage("part2_mesh"):
            transfer = _to_level(model, run, transfer, level2)
    with run.monitor.stage("part2"):
        stress_vm, mesh2, ft2 = run_part2(model, run, transfer, layout, data)
    save_results(model, data, stress_vm, mesh2, ft2, run.fields.parent / "shoulder.npz")


def _compliant_part1(model: ShoulderModel, run: RunContext, layout: list[dict]):
    """Part 1 that sees the bones' compliance (:mod:`.correction`); (data, transfer)."""
    part1 = Part1(model, run, layout, keep=True)
    try:
        data, transfer = part1.run()
        # its LU factors wait for the correction, whose first solve factorizes afresh anyway:
        # freed while part 2 runs
        part1.system.snes.getKSP().reset()
        X_tied, _ = part1.system.tied_positions("scapula")
        scapula: list[Offsets] = []
        probe: list[NodalValues] = []

        def collect(k: int, part2) -> None:
            if not probe:
                probe.append(NodalValues(part2.V, X_tied, "part 1's scapula nodes"))
            springs = {b.name: b.translation.copy() for b in part2.bodies}
            scapula.append(Offsets(probe[0](part2.u), springs))

        scratch = Recorder(run.recorder.comm, run.recorder.folder)
        rigid: dict = {}
        with run.monitor.stage("part2_uncorrected"):
            run_part2(
                model,
                run,
                transfer,
                layout,
                rigid,
                recorder=scratch,
                write_fields=False,
                on_step=collect,
            )
        adopt(run.recorder, scratch, replace_plain=False)
        release_memory()  # the first part 2's solver and spaces are gone
        nodes = {"scapula": X_tied}
        offsets = [{"scapula": o} for o in scapula]
        if model.params.part1_humerus:  # the humerus's deformation too (.humerus)
            nodes["humerus"], _ = part1.system.tied_positions("humerus")
            with run.monitor.stage("humerus"):
                humerus = humerus_offsets(model, run, part1, nodes["humerus"])
            for by_body, o in zip(offsets, humerus, strict=True):
                by_body["humerus"] = o
        model.meshes.pop("humerus", None)
        release_memory()
        with run.monitor.stage("part1_correction"):
            corrected, transfer, stop = correct_part1(part1, nodes, offsets, run)
    finally:
        part1.destroy()
    if stop is not None:
        run.recorder.set_status("incomplete", stop)
        data["stop"] = stop
    data[UNCORRECTED + "von_mises_series"] = rigid.get("von_mises_series", [])
    for key in ("angles_deg", "glenoid_pressure", "glenoid_shear"):
        data[UNCORRECTED + key] = data[key]
    data.update(corrected)
    transfer.save(run.fields.parent / "transfer.npz", model.comm)
    return data, transfer


def _to_level(model: ShoulderModel, run: RunContext, transfer: Transfer, level: str) -> Transfer:
    """Mesh the scapula at ``level`` and carry part 1's loads onto it (:mod:`.load_map`)."""
    del model.meshes["scapula"]
    sm = model.meshes["scapula"] = scapula_at(model, level)
    names = SCAPULA_LOAD_SURFACES + (("scapula_surface",) if model.params.scapula_contact else ())
    tags = [S.MARKERS[name].id for name in names]
    mapping = load_map(transfer.points, surface_triangles(sm.mesh, sm.facet_tags, tags))
    rec = run.recorder
    rec.set_probe("load_map_max_move", float(mapping.moves.max(initial=0.0)), "m")
    for angle, f in zip(transfer.angles, transfer.forces, strict=True):
        error = mapping.moment_error(np.asarray(f), transfer.reference)
        rec.add_series_point("load_map_moment_error", np.degrees(angle), error, "deg", "1")
    forces = [mapping.forces(np.asarray(f)) for f in transfer.forces]
    return replace(transfer, points=mapping.points, forces=forces)


@dataclass
class Transfer:
    """Part 1's loads on the scapula and its rigid motion at each output angle.

    Attributes:
        reference: The scapula's reference point (m): the centroid of the glenoid cartilage's
            bone side, about which part 2's floating frame turns.
        points: The loaded nodes (m, reference geometry), gathered on every rank.
        angles: The output angles (rad).
        forces: Per angle, the nodal forces (N, (n, 3), at ``points``) on the scapula.
        translation: Per angle, the scapula's translation (m).
        rotation: Per angle, the scapula's rotation (3 x 3).
        humerus_rotation: Per angle, the humerus's rotation (3 x 3).
        spring_offsets: Per angle, where the compliant correction attached the scapula's
            springs ({name: offset} m, scapula frame; :mod:`.correction`); empty: at their
            points.
        point_offsets: Per angle, where the compliant correction had moved the loaded nodes
            ((n, 3) m, scapula frame); empty: at ``points``.
    """

    reference: np.ndarray
    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    angles: list = field(default_factory=list)
    forces: list = field(default_factory=list)
    translation: list = field(default_factory=list)
    rotation: list = field(default_factory=list)
    humerus_rotation: list = field(default_factory=list)
    spring_offsets: list = field(default_factory=list)
    point_offsets: list = field(default_factory=list)

    def save(self, path: Path, comm: MPI.Comm) -> None:
        """Write ``transfer.npz`` (collective)."""
        save_npz(
            path,
            {
                "reference": self.reference,
                "points": self.points,
                "forces": np.asarray(self.forces),
                "angles_rad": np.asarray(self.angles),
                "translation": np.asarray(self.translation),
                "rotation": np.asarray(self.rotation),
            },
            comm,
        )


class _TransferRecorder:
    """Records part 1's loads on the scapula into a :class:`Transfer` at each output."""

    def __init__(
        self,
        V,
        ft,
        system: RigidSystem,
        bones: tuple[RigidBody, RigidBody],
        transfer: Transfer,
    ):
        self.system, self.transfer = system, transfer
        self.scapula, self.humerus = bones
        # and the master of the muscle-scapula contact (muscle_contact = bones): the muscles'
        # pressure on the scapula
        tags = [S.MARKERS[n].id for n in SCAPULA_LOAD_SURFACES] + [S.SCAPULA_CONTACT_SURFACE.id]
        self.loads = SurfaceForces(V, ft, tags)
        transfer.points = self.loads.points

    def __call__(self, target: float, residual: PETSc.Vec | None = None) -> None:
        """Record at output angle ``target`` (rad) (collective).

        ``residual``: the system's FE residual at this state, if already assembled.
        """
        tr = self.transfer
        if residual is None:
            residual = self.system.assembled_residual()
        tr.angles.append(target)
        tr.forces.append(self.loads(residual))
        tr.translation.append(self.scapula.translation.copy())
        tr.rotation.append(self.scapula.rotation.copy())
        tr.humerus_rotation.append(self.humerus.rotation.copy())


def part1_springs(surf, tags, layout: list[dict], length: float) -> list[Spring]:
    """The flexible elements on the rigid bones: from their patch's centroid to the ground."""
    springs = []
    for sp in layout:
        c = surface_centroid(surf, tags, sp["patch"])
        sp["centre"] = c
        springs.append(
            Spring(sp["name"], sp["bone"], c, GROUND, c + length * sp["direction"], sp["stiffness"])
        )
    return springs


def part1_ties(ft, cell_tags, params: ShoulderParameters) -> tuple[list[Tie], dict]:
    """The soft tissues' surfaces tied to the rigid bones and the actuator, and their tags."""
    ties = [Tie("humerus", n) for n in HUMERUS_TIES]
    ties += [Tie("scapula", n) for n in SCAPULA_LOAD_SURFACES]
    ties.append(Tie("actuator", "subscapularis_origin"))
    tied = surfaces(ft, [t.surface for t in ties])
    layers = (
        (params.humeral_head_contact, "humerus", S.HUMERUS_HEAD_LAYER),
        (params.scapula_contact, "scapula", S.SCAPULA_LAYER),
    )
    for on, bone, layer in layers:
        if on:  # the bone cells under the muscles' sliding master: carried whole by the bone
            tied[layer.name] = (cell_tags, layer.id)
            ties.append(Tie(bone, layer.name))
    return ties, tied


#: Part 1's own solver options: MUMPS with the QAMD ordering (ICNTL(7) = 6) and without its
#: automatic scaling (ICNTL(8) = 0). Measured at ``paper``, part 1's LU time over 0-60 deg:
#: 9.5 s with MUMPS's automatic ordering, 7.8 s with QAMD, 7.8 AMF (2), 7.9 AMD (0), 9.1 METIS
#: (5), 9.1 PORD (4), 9.2 SCOTCH (3); then 7.7-8.0 s scaled, 6.8-7.0 s unscaled (two runs
#: each); the same iterations, results within 1e-14. (The rigid bodies' rows couple to every
#: tied node: AMD-like orderings suit them.) Not the coupled run's: QAMD made its LU 31 %
#: slower at ``medium`` (52.8 s against 40.2) and its peak memory 19 % higher; unscaled, its
#: LU took 35.2 s against 42.9 at ``medium`` but 236.1 against 229.9 at ``paper`` (the level
#: of the study), so it keeps MUMPS's choices.
PART1_OPTIONS = {"mat_mumps_icntl_7": 6, "mat_mumps_icntl_8": 0}


class Part1:
    """Part 1: rigid bones, deformable soft tissues (collective).

    :meth:`run` steps through the output angles and writes ``transfer.npz``; with ``keep`` the
    system stays alive after it, with the converged state of every output angle, for the
    compliant correction (:mod:`.correction`); :meth:`destroy` frees it.
    """

    def __init__(self, model: ShoulderModel, run: RunContext, layout: list[dict], keep: bool):
        self.model, self.run_context, self.keep = model, run, keep
        p = model.params
        sm = model.meshes["rigid-bone"]
        d = displacement(model, "rigid-bone")
        mesh, ct_, ft, V, u, w, dx = d.mesh, d.cell_tags, d.facet_tags, d.V, d.u, d.w, d.dx
        self.comm = mesh.comm
        F, self.volumetric = soft_tissue_residual(u, w, dx, ct_, p)
        self.contact = contact = joint_contact(V, u, ft, p)
        humerus = RigidBody("humerus", np.zeros(3))
        scapula_ref = patch_centroid(mesh, ft, S.MARKERS["glenoid_cartilage_bone"].id)
        scapula = RigidBody("scapula", scapula_ref)
        origin = patch_centroid(mesh, ft, S.MARKERS["subscapularis_origin"].id)
        actuator = RigidBody("actuator", origin, prescribed=True)
        self.springs = part1_springs(sm.bone_surface, sm.bone_surface_tags, layout, p.spring_length)
        ties, tied = part1_ties(ft, ct_, p)
        check = SoftTissueCheck(
            u, ct_, p.trial_check, p.quadrature_degree, trial_i1bar_max(p.muscle_beta)
        )
        self.system = system = RigidSystem(
            [humerus, scapula, actuator],
            self.springs,
            u=u,
            residual=F,
            surfaces=tied,
            ties=ties,
            name="shoulder_part1",
            options=SNES_OPTIONS | PART1_OPTIONS | dict(run.options or {}),
            form_compiler_params=p.quadrature(),
            contact=contact,
            admissible=check,
            volumetric=self.volumetric,
            uncondensed=uncondensed(p, self.volumetric),
        )
        self.transfer = Transfer(reference=scapula_ref)
        self.record = _TransferRecorder(V, ft, system, (scapula, humerus), self.transfer)
        #: Part 1's loads on the humerus, for the compliant correction (with ``keep`` only)
        self.humerus = None
        if keep and p.part1_humerus:
            self.humerus = HumerusRecorder(V, ft, humerus, HUMERUS_TIES, p)
        self.probe = Probe(u, ct_, ft, contact, p, self.volumetric)
        #: Per output angle: the system's snapshot, the angle's target (rad), the
        #: incompressible tissue's multipliers (or None); with ``keep`` only.
        self.states: list[tuple] = []
        self.job = Stepping(
            system=system,
            contact=contact,
            actuator=actuator,
            rotation=lambda: humerus.rotation,
            measure=rigid_twist(humerus, 0, model.shaft_axis),
            probe=self.probe,
            u=u,
            label="part1",
            check=check,
            stage="part1",
            on_output=self._on_output,
        )

    def _on_output(self, target: float) -> None:
        residual = self.system.assembled_residual()  # the loads on both bones
        self.record(target, residual)
        if self.humerus is not None:
            self.humerus(target, residual)
        if self.keep:
            vol = self.volumetric
            multipliers = None if vol is None else vol.multiplier.copy()
            state = (self.system.snapshot(), self.system.control.target, multipliers)
            self.states.append(state)

    def run(self) -> tuple[dict, Transfer]:
        """Step through the output angles (collective); writes ``transfer.npz``.

        Returns:
            The stepping's outputs (:func:`stepping.run_steps`) and the transfer to part 2.
        """
        run = self.run_context
        try:
            data = run_steps(self.model, run, self.job)
            run.recorder.extra("dofs_part1", unknowns(self.system))
            self.transfer.save(run.fields.parent / "transfer.npz", self.comm)
        finally:  # a failed run too (with ``keep`` the caller destroys it)
            if not self.keep:
                self.destroy()
        return data, self.transfer

    def destroy(self) -> None:
        """Free the solver and the probes."""
        self.probe.destroy()
        if self.volumetric is not None:
            self.volumetric.destroy()
        self.system.destroy()
        self.states.clear()


def run_part1(model: ShoulderModel, run: RunContext, layout: list[dict]) -> tuple[dict, Transfer]:
    """Part 1: rigid bones, deformable soft tissues (collective); writes ``transfer.npz``.

    Returns:
        The stepping's outputs (:func:`stepping.run_steps`) and the transfer to part 2.
    """
    return Part1(model, run, layout, keep=False).run()
