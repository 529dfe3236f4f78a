"""What a shoulder run records besides the stepping's series: probes and ``shoulder.npz``.

The scapula's von Mises series, the split of the Newton time, the unknowns of a solve, and
the arrays of ``shoulder.npz`` (read by :mod:`shoulder_fem.families.shoulder.report`), written
the same way by both methods.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from mpi4py import MPI
from scipy.spatial import cKDTree

from shoulder_fem.engine.contact import Contact
from shoulder_fem.engine.rigid_system import RigidSystem
from shoulder_fem.families.shoulder.geometry import patch_centroid, swing_angle, swing_parts
from shoulder_fem.families.shoulder.interactions import MUSCLE_BONE_PAIRS
from shoulder_fem.families.shoulder.measures import VonMises
from shoulder_fem.families.shoulder.model import ShoulderModel
from shoulder_fem.io.output import atomic_savez
from shoulder_fem.io.results import Recorder
from shoulder_fem.meshes import shoulder as S

#: Prefix of the rigid (paper's) decoupling's series, probes and arrays in the results of a
#: run with a compliant part 1 (``part1_bones``, :mod:`.correction`), which replaces the plain ones.
UNCORRECTED = "uncorrected_"

__all__ = [
    "record_muscle_bone",
    "record_swing",
    "record_time_split",
    "record_von_mises",
    "save_npz",
    "save_results",
    "unknowns",
]


def record_muscle_bone(recorder: Recorder, contact: Contact, x: float) -> None:
    """The rotator cuff on the bones at output angle ``x`` (deg; collective; muscle contact only).

    Per pair (``muscle_humerus``, ``muscle_scapula``): ``<pair>_contact_force`` and
    ``<pair>_penetration``; per muscle and bone ``<muscle>_<bone>_contact_force``; per muscle
    ``<muscle>_bone_contact_force`` (both bones' forces added as vectors); over all pairs
    ``muscle_bone_contact_force`` and ``muscle_bone_penetration`` (before the scapula's pair:
    the humeral head's alone). Forces in N (magnitudes of the force on the muscles' faces),
    penetrations in m.
    """
    names = {p.name for p in contact.pairs}
    if not names & {pair for pair, _, _ in MUSCLE_BONE_PAIRS.values()}:
        return
    tagged = contact.resultants(by_tag=True)
    total, deepest, per_muscle = np.zeros(3), 0.0, {}
    for bone, (pair, faces, _) in MUSCLE_BONE_PAIRS.items():
        if pair not in names:
            continue
        by_tag = tagged[pair]
        force = sum((r["force"] for r in by_tag.values()), np.zeros(3))
        pen = float(max(r["max_penetration"] for r in by_tag.values()))
        recorder.add_series_point(f"{pair}_contact_force", x, _norm(force), "deg", "N")
        recorder.add_series_point(f"{pair}_penetration", x, pen, "deg", "m")
        for muscle, tags in zip(S.MUSCLES, faces, strict=True):
            f = sum((by_tag[t.id]["force"] for t in tags if t.id in by_tag), np.zeros(3))
            per_muscle[muscle] = per_muscle.get(muscle, np.zeros(3)) + f
            recorder.add_series_point(f"{muscle}_{bone}_contact_force", x, _norm(f), "deg", "N")
        total, deepest = total + force, max(deepest, pen)
    for muscle, f in per_muscle.items():
        recorder.add_series_point(f"{muscle}_bone_contact_force", x, _norm(f), "deg", "N")
    recorder.add_series_point("muscle_bone_contact_force", x, _norm(total), "deg", "N")
    recorder.add_series_point("muscle_bone_penetration", x, deepest, "deg", "m")


def _norm(v: np.ndarray) -> float:
    return float(np.linalg.norm(v))


def record_von_mises(
    recorder: Recorder, stress_vm: VonMises, x: float, data: dict, comm: MPI.Comm
) -> None:
    """Record the scapula's von Mises stress at output angle ``x`` (deg) (collective).

    Its maximum as a series point, its nodal values in ``data``: ``von_mises`` (points,
    values) of the last output, and ``von_mises_series`` [(angle, values), ...] of every one.
    """
    field_vm = stress_vm.update()
    local = float(field_vm.x.array.max()) if len(field_vm.x.array) else 0.0
    recorder.add_series_point(
        "scapula_max_von_mises", x, comm.allreduce(local, op=MPI.MAX), "deg", "Pa"
    )
    data["von_mises"] = stress_vm.nodal(comm)
    data["von_mises_angle_deg"] = x
    data.setdefault("von_mises_series", []).append((x, data["von_mises"][1]))


def record_swing(recorder: Recorder, x: float, R: np.ndarray, shaft_axis: np.ndarray) -> None:
    """The humerus's swing at output ``x`` deg (series ``humeral_swing``, deg) and its parts.

    ``humeral_swing_elevation``: the change of the shaft's angle from the downward vertical
    (positive: raised, as in abduction; what vertical distal elements resist);
    ``humeral_swing_azimuth``: the turn of its horizontal direction about the vertical
    (positive: the distal end from lateral towards anterior). ``R``: the humerus's rotation;
    ``shaft_axis``: unit, proximal (:func:`.geometry.swing_parts`).
    """
    recorder.add_series_point(
        "humeral_swing", x, math.degrees(swing_angle(R, shaft_axis)), "deg", "deg"
    )
    for name, a in zip(("elevation", "azimuth"), swing_parts(R, shaft_axis), strict=True):
        recorder.add_series_point(f"humeral_swing_{name}", x, math.degrees(a), "deg", "deg")


def record_time_split(
    recorder: Recorder, label: str, system: RigidSystem, contact: Contact | None
) -> None:
    """Where a stepping's Newton time went (probes ``<label>_time_*_s``, wall s, slowest rank).

    ``newton``: in the Newton solves in all; ``residual`` and ``jacobian``: their evaluations
    (FE assembly, contact, the reduction to the rigid bodies; within ``jacobian``:
    ``jacobian_fe_assembly`` and ``jacobian_reduction``, the products Pᵀ K P); ``linear``: the
    rest of ``newton`` (the LU factorizations and solves, or the preconditioner's set-up and
    the Krylov iterations); ``contact``: the contact search and assembly, part of ``residual``
    and ``jacobian`` (none without ``contact``).
    """
    st = system.stats
    times = {
        "newton": st.snes_s,
        "residual": st.residual_s,
        "jacobian": st.jacobian_s,
        "jacobian_fe_assembly": st.fe_assembly_s,
        "jacobian_reduction": st.reduction_s,
        "linear": max(st.snes_s - st.residual_s - st.jacobian_s, 0.0),
    }
    if contact is not None:
        times["contact"] = contact.stats.search_s + contact.stats.assembly_s
    for key, value in times.items():
        worst = system.comm.allreduce(float(value), op=MPI.MAX)
        recorder.set_probe(f"{label}_time_{key}_s", worst, "s")


def unknowns(system: RigidSystem) -> int:
    """Unknowns of a system's Newton solves: free FE DOFs and six per rigid body (collective).

    Tied and fixed nodes are not unknowns (the rigid-bone mesh carries tied bone nodes).
    """
    x = system.reduced_vector()
    n = x.getSize()
    x.destroy()
    return int(n)


def save_npz(path: Path, arrays: dict, comm: MPI.Comm) -> None:
    """Write ``arrays`` to ``path`` atomically (rank 0 writes, every rank waits)."""
    if comm.rank == 0:
        atomic_savez(path, arrays)
    comm.Barrier()


def save_results(
    model: ShoulderModel, data: dict, stress_vm: VonMises, mesh, ft, path: Path
) -> None:
    """shoulder.npz of one run (see :mod:`shoulder_fem.families.shoulder.report`) (collective).

    ``data``: the stepping's outputs (:func:`stepping.run_steps`); ``mesh``, ``ft``: the mesh
    of ``stress_vm`` and its facet tags.
    """
    comm = mesh.comm
    points, vm = data.get("von_mises", (np.zeros((0, 3)), np.zeros(0)))
    series = data.get("von_mises_series", [])
    cell_points, cells = stress_vm.cells(comm)
    # the nodal values in the order of the cell points
    tree = cKDTree(points) if len(points) else None
    order = tree.query(cell_points)[1] if tree is not None else np.zeros(0, dtype=int)
    section = patch_centroid(mesh, ft, S.MARKERS["scapula_section"].id)[2]
    centre, axis = model.info["glenoid_frame"]
    n_out = len(data["angles_deg"])
    arrays = {
        "angles_deg": np.asarray(data["angles_deg"], dtype=float),
        "glenoid_points": np.asarray(data["glenoid_points"]),
        "glenoid_pressure": np.asarray(data["glenoid_pressure"]).reshape(n_out, -1),
        "glenoid_shear": np.asarray(data["glenoid_shear"]).reshape(n_out, -1),
        "glenoid_centre": centre,
        "glenoid_axis": axis,
        "scapula_points": cell_points,
        "scapula_cells": cells,
        "scapula_von_mises": np.asarray(vm)[order] if len(vm) else np.zeros(len(cell_points)),
        "von_mises_angle_deg": float(data.get("von_mises_angle_deg", math.nan)),
        "von_mises_angles_deg": np.array([a for a, _ in series], dtype=float),
        "scapula_von_mises_series": np.array(
            [np.asarray(v)[order] for _, v in series], dtype=float
        ).reshape(len(series), len(cell_points)),
        "section_z": float(section),
        "final_angle_deg": float(data["final_angle_deg"]),
    }
    if UNCORRECTED + "von_mises_series" in data:  # a compliant part 1 (:mod:`.correction`)
        older = data[UNCORRECTED + "von_mises_series"]
        for key in ("angles_deg", "glenoid_pressure", "glenoid_shear"):
            arrays[UNCORRECTED + key] = np.asarray(data[UNCORRECTED + key], dtype=float)
        arrays[UNCORRECTED + "von_mises_angles_deg"] = np.array([a for a, _ in older], float)
        arrays[UNCORRECTED + "scapula_von_mises_series"] = np.array(
            [np.asarray(v)[order] for _, v in older], dtype=float
        ).reshape(len(older), len(cell_points))
    for key, value in data.get("arrays", {}).items():
        arrays[key] = value
    save_npz(path, arrays, comm)
