"""Method ``coupled``: the whole joint in one finite-strain problem, every body deformable.

The bones are Saint Venant-Kirchhoff with E from the density image, the soft tissues as in
:mod:`.interactions`; one Newton solve per step of :mod:`.stepping`. The spring plates and the
actuator plate are rigid bodies tied to the mesh (:class:`~shoulder_fem.engine.rigid_system.
RigidSystem`); the humerus's rotation is the best fit of its nodes' motion.
"""

from __future__ import annotations

import dolfinx
import numpy as np

from shoulder_fem.engine.block_split import split_options
from shoulder_fem.engine.rigid_system import RigidBody, RigidSystem, Tie
from shoulder_fem.families.base import RunContext
from shoulder_fem.families.shoulder.geometry import best_fit_rotation, patch_centroid
from shoulder_fem.families.shoulder.interactions import (
    bone_fields,
    cauchy_stress,
    joint_contact,
    soft_tissue_residual,
    spring_layout,
    spring_plates,
    surfaces,
    uncondensed,
)
from shoulder_fem.families.shoulder.measures import Probe, VonMises
from shoulder_fem.families.shoulder.model import ShoulderModel, displacement
from shoulder_fem.families.shoulder.outputs import save_results, unknowns
from shoulder_fem.families.shoulder.stepping import SNES_OPTIONS, Stepping, run_steps
from shoulder_fem.families.shoulder.trial import SoftTissueCheck, trial_i1bar_max
from shoulder_fem.families.shoulder.twist import fitted_twist
from shoulder_fem.forms import materials
from shoulder_fem.forms import virtual_power as vp
from shoulder_fem.meshes import shoulder as S

__all__ = ["run_coupled"]


def run_coupled(model: ShoulderModel, run: RunContext) -> None:
    """Method #1: every body deformable, finite strain (collective)."""
    p = model.params
    d = displacement(model, "deformable")
    mesh, ct_, ft, V, u, w, dx = d.mesh, d.cell_tags, d.facet_tags, d.V, d.u, d.w, d.dx
    comm = mesh.comm
    rho, E = bone_fields(mesh, ct_, model.image, p)
    bone = materials.SaintVenantKirchhoff(E, materials.BONE_NU)
    F, volumetric = soft_tissue_residual(u, w, dx, ct_, p)
    F += vp.internal_power_finite(bone, u, w, dx(S.HUMERUS.id))
    F += vp.internal_power_finite(bone, u, w, dx(S.SCAPULA.id))
    contact = joint_contact(V, u, ft, p)
    bodies, ties, springs = spring_plates(mesh, ft, spring_layout(p), p.spring_length)
    origin = patch_centroid(mesh, ft, S.MARKERS["subscapularis_origin"].id)
    actuator = RigidBody("actuator", origin, prescribed=True)
    bodies.append(actuator)
    ties.append(Tie("actuator", "subscapularis_origin"))
    check = SoftTissueCheck(
        u, ct_, p.trial_check, p.quadrature_degree, trial_i1bar_max(p.muscle_beta)
    )
    # each bone's share of every Newton step turns by a finite rotation (on the paper's supports
    # the humerus swings by tens of degrees and the scapula turns with it: a linear step
    # strains the stiff bone; engine/rigid_system/corotation.py; with the cartilages in the
    # regions too, measured at coarse: 2 cut-backs over 0-60 deg instead of 1)
    bones = [
        dolfinx.fem.locate_dofs_topological(V, 3, ct_.find(bone.id))
        for bone in (S.HUMERUS, S.SCAPULA)
    ]
    split = p.coupled_solver == "split"
    solver = split_options() if split else {}
    system = RigidSystem(
        bodies,
        springs,
        u=u,
        residual=F,
        surfaces=surfaces(ft, [t.surface for t in ties]),
        ties=ties,
        name="shoulder_coupled",
        options=SNES_OPTIONS | solver | dict(run.options or {}),
        form_compiler_params=p.quadrature(),
        contact=contact,
        admissible=check,
        volumetric=volumetric,
        rigid_regions=bones,
        near_nullspace=split,
        uncondensed=not split and uncondensed(p, volumetric),
    )
    if split:  # the bones and their plates, the soft tissues, the actuator's control (border)
        system.split_fields(np.concatenate(bones), [b.name for b in bodies if b is not actuator])
    humerus_dofs = bones[0][bones[0] < V.dofmap.index_map.size_local]
    X_h = V.tabulate_dof_coordinates()[humerus_dofs]

    def rotation() -> np.ndarray:
        x = X_h + u.x.array.reshape(-1, 3)[humerus_dofs]
        return best_fit_rotation(X_h, x, comm)

    stress_vm = VonMises(mesh, ct_, cauchy_stress(bone, u), p.nodal_stress)
    probe = Probe(u, ct_, ft, contact, p, volumetric)
    job = Stepping(
        system=system,
        contact=contact,
        actuator=actuator,
        rotation=rotation,
        measure=fitted_twist(u, humerus_dofs, model.shaft_axis),
        probe=probe,
        u=u,
        label="coupled",
        check=check,
        stage="rotation",
        stress=stress_vm,
    )
    try:
        data = run_steps(model, run, job)
        run.recorder.extra("dofs_coupled", unknowns(system))
        save_results(model, data, stress_vm, mesh, ft, run.fields.parent / "shoulder.npz")
    finally:  # a failed run too: its solver's options leave PETSc's database with it
        probe.destroy()
        if volumetric is not None:
            volumetric.destroy()
        system.destroy()
