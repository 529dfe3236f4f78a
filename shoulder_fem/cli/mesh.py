"""``shoulder-fem mesh SCENE --level L --variant deformable|rigid-bone --out DIR``.

Builds the parametric shoulder of a ``family = "shoulder"`` scene and writes, atomically:

* ``DIR/mesh.xdmf``: the mesh (m) with its cell tags ("Cell tags") and facet tags ("Facet
  tags"); for ``rigid-bone`` also ``DIR/bone_surface.xdmf`` (the rigid bones' triangle surfaces);
* ``DIR/density.nii.gz`` (the CT-like phantom, or the given ``--ct`` is used instead) and
  ``DIR/density.xdmf`` (nodal density, kg/m^3, and modulus E = E0 (rho/rho0)^2, Pa, P1);
* ``DIR/mesh.json``: parameters, level sizes, DOF and element counts per body, quality, times;
* ``DIR/mesh.png``: bones, cartilages and muscles in distinct colours, and a density slice.

Input errors raise :class:`shoulder_fem.scene.SceneError` or
:class:`shoulder_fem.io.output.OutputError` (exit status 2 in the CLI).
"""

from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path

from shoulder_fem.cli.args import add_out_arguments, add_scene_arguments

logger = logging.getLogger(__name__)

ELEMENT = {
    "cell": "straight-sided tetrahedron",
    "bone": "P2 displacement (compressible, nu = 0.3)",
    "cartilage_and_muscle": (
        "sized for Taylor-Hood P2/P1 (P2 displacement, continuous P1 pressure per body); the "
        "runs solve P2 displacement, the P1 pressure of the incompressible bodies condensed "
        "out, not solved (the cartilages by default; soft_tissue_formulation)"
    ),
    "dof_count": (
        "dofs = dofs_displacement (3 x P2 nodes of the mesh) + dofs_pressure (P1 vertices of "
        "each soft body, which no run solves as unknowns) + 6 per rigid bone (rigid-bone "
        "variant); dofs_p1 = 3 x vertices is the count of a linear element, for comparison "
        "with the paper's 8-node hexahedra"
    ),
}


def add_mesh_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``mesh`` sub-command to the CLI's sub-parsers."""
    p = subparsers.add_parser("mesh", help="build the mesh of a shoulder scene")
    p.add_argument("scene", help="built-in scene name or path to a .toml scene file")
    add_scene_arguments(p, example="head_radius=22mm")
    p.add_argument(
        "--variant",
        choices=["deformable", "rigid-bone"],
        default="deformable",
        help="bone volumes meshed (deformable) or only the bone surfaces (rigid-bone)",
    )
    p.add_argument(
        "--ct", type=Path, default=None, help="CT image (NIfTI file or DICOM folder) for density"
    )
    p.add_argument(
        "--voxel", type=float, default=1.5e-3, help="phantom voxel size in m (default 1.5e-3)"
    )
    add_out_arguments(p)
    return p


def cmd_mesh(args) -> int:
    """Build, measure and write the mesh of a shoulder scene; returns the exit status (0)."""
    from mpi4py import MPI

    from shoulder_fem.cli.mesh_figure import plot_mesh
    from shoulder_fem.io import ct as dens
    from shoulder_fem.io.output import OutputDir, atomic_write_json
    from shoulder_fem.meshes import shoulder as sh
    from shoulder_fem.scene import SceneError

    comm = MPI.COMM_WORLD
    t0 = time.perf_counter()
    scene, level, sizes, geometry = _shoulder_scene(args)
    values = scene.values()
    calibration = dens.Calibration(
        values.get("ct_density_intercept", dens.Calibration.intercept),
        values.get("ct_density_slope", dens.Calibration.slope),
    )
    if args.ct is None and values.get("ct_image"):
        args.ct = Path(values["ct_image"])
    if args.ct is not None:
        try:
            image = dens.read_ct(args.ct)
        except (OSError, ValueError) as err:
            raise SceneError(f"--ct {args.ct}: {err}") from None
    out = OutputDir(args.out, comm, replace=args.force)
    with out:
        try:
            sm = sh.build_shoulder_mesh(comm, geometry, sizes, args.variant)
        except ValueError as err:
            raise SceneError(f"{scene.source}: {err}") from None
        t_mesh = time.perf_counter() - t0
        if args.ct is None:
            image = dens.shoulder_phantom(geometry, voxel=args.voxel, calibration=calibration)
            if comm.rank == 0:
                dens.write_nifti(image, out.path / "density.nii.gz")
        _write_xdmf(comm, out.path, sm)
        if args.ct is not None:  # the phantom covers the bones by design, clamped beyond
            _check_scan(comm, sm.mesh, image, args.ct, calibration)
        rho, modulus = dens.nodal_modulus(sm.mesh, image, calibration)
        _write_density(comm, out.path / "density.xdmf", sm.mesh, rho, modulus)
        stats = mesh_statistics(sm)
        summary = _summary(args, scene, level, sizes, stats, calibration)
        summary["timing"] = {
            "geometry_s": sm.info.get("geometry_s"),
            "meshing_s": sm.info.get("meshing_s"),
            "gmsh_s": sm.info.get("build_s"),
            "mesh_total_s": t_mesh,
            "wall_s": time.perf_counter() - t0,
        }
        summary["ranks"] = comm.size
        plot_mesh(comm, out.path / "mesh.png", sm, image, calibration)
        summary["timing"]["wall_s"] = time.perf_counter() - t0
        if comm.rank == 0:
            atomic_write_json(out.path / "mesh.json", summary)
        comm.Barrier()
    if comm.rank == 0:
        print(_summary_line(summary, args.variant, out.final), flush=True)
    return 0


def _shoulder_scene(args):
    """The scene of ``args``, its level, the level's sizes and the geometry, all checked.

    Raises:
        SceneError: for a scene of another family, bad sizes or geometry, or ``--voxel`` <= 0.
    """
    from shoulder_fem.meshes import shoulder as sh
    from shoulder_fem.scene import SceneError, load_scene

    scene = load_scene(args.scene).with_overrides(list(args.sets))
    if scene.family != "shoulder":
        raise SceneError(
            f"{scene.source}: scene '{scene.name}' is of family '{scene.family}'; "
            "the mesh command builds 'shoulder' scenes"
        )
    from shoulder_fem.families.shoulder.model import check_effective, resolve

    check_effective(scene)
    scene = resolve(scene)
    level = args.level or scene.default_level
    sizes = scene.level(level)
    try:
        sh.check_sizes(sizes)
    except ValueError as err:
        raise SceneError(f"{scene.source}: [levels.{level}]: {err}") from None
    try:
        geometry = sh.geometry_from_values(scene.values())
        geometry.validate()
    except (TypeError, ValueError) as err:
        raise SceneError(f"{scene.where(*scene.overridden)}: {err}") from None
    if not args.voxel > 0:
        raise SceneError(f"--voxel {args.voxel}: must be > 0 (m)")
    return scene, level, sizes, geometry


def _check_scan(comm, mesh, image, source, calibration) -> None:
    """Refuse a CT image that misses the model, warn when partly or uniform (collective)."""
    from shoulder_fem.io import ct as dens
    from shoulder_fem.scene import SceneError

    n_owned = mesh.geometry.index_map().size_local
    try:
        dens.check_scan(image, mesh.geometry.x[:n_owned], comm, f"--ct {source}", calibration)
    except ValueError as err:
        raise SceneError(str(err)) from None


def _summary(args, scene, level: str, sizes: dict, stats: dict, calibration) -> dict:
    """``mesh.json`` but its timing and ranks: what was built, its counts, the density source."""
    from shoulder_fem.io import ct as dens
    from shoulder_fem.meshes import shoulder as sh

    return {
        "scene": scene.name,
        "command": "mesh",
        "level": level,
        "variant": args.variant,
        "parameters": {k: {"value": p.value, "unit": p.unit} for k, p in scene.parameters.items()},
        "sizes_m": sizes,
        "element": ELEMENT,
        "markers": {m.name: {"id": m.id, "dim": m.dim} for m in sh.VOLUMES + sh.SURFACES},
        "surface_sets": sh.SURFACE_SETS,
        **stats,
        "density": {
            "source": str(args.ct) if args.ct else "phantom (density.nii.gz)",
            "calibration": {"intercept": calibration.intercept, "slope": calibration.slope},
            "law": "E = max(E0 (rho/rho0)^2, floor), E0 = 15 GPa, rho0 = 1800 kg/m^3",
            "floor_pa": dens.E_FLOOR,
        },
    }


def _summary_line(summary: dict, variant: str, final: Path) -> str:
    """The command's one line on stdout: counts, gmsh times and the output folder."""
    tot, timing = summary["totals"], summary["timing"]
    return (
        f"mesh: {summary['level']} {variant}: {tot['cells']} cells, {tot['dofs']} DOF "
        f"({tot['dofs_displacement']} P2 displacement + {tot['dofs_pressure']} P1 pressure"
        f"{' + 12 rigid' if variant == 'rigid-bone' else ''}), gmsh "
        f"{timing['gmsh_s']:.1f} s (geometry {timing['geometry_s']:.1f}"
        f" s, meshing {timing['meshing_s']:.1f} s) -> {final}"
    )


def _write_xdmf(comm, folder: Path, sm) -> None:
    import dolfinx

    with dolfinx.io.XDMFFile(comm, folder / "mesh.xdmf", "w") as f:
        f.write_mesh(sm.mesh)
        sm.mesh.topology.create_connectivity(sm.mesh.topology.dim - 1, sm.mesh.topology.dim)
        f.write_meshtags(sm.cell_tags)
        f.write_meshtags(sm.facet_tags)
    if sm.bone_surface is not None:
        with dolfinx.io.XDMFFile(comm, folder / "bone_surface.xdmf", "w") as f:
            f.write_mesh(sm.bone_surface)
            f.write_meshtags(sm.bone_surface_tags)


def _write_density(comm, path: Path, mesh, rho, modulus) -> None:
    import dolfinx

    with dolfinx.io.XDMFFile(comm, path, "w") as f:
        f.write_mesh(mesh)
        f.write_function(rho)
        f.write_function(modulus)


def mesh_statistics(sm) -> dict:
    """Per-body counts (cells, vertices, P1 and P2 DOF), totals and quality (collective).

    Quality: mean ratio q = 6 sqrt(2) V / l_rms^3 of the tetrahedra (1 = regular).
    """
    mesh = sm.mesh
    tdim = mesh.topology.dim
    mesh.topology.create_entities(1)
    n_local = mesh.topology.index_map(tdim).size_local
    bodies = _body_counts(mesh, sm.cell_tags, n_local)
    totals = _totals(mesh, bodies, rigid_bone=sm.bone_surface is not None)
    quality = _quality(mesh, n_local)
    facet_counts = _facet_counts(mesh, sm.facet_tags)
    return {"bodies": bodies, "totals": totals, "quality": quality, "facets": facet_counts}


def _body_counts(mesh, ct, n_local: int) -> dict:
    """Cells, vertices, P2 nodes and DOF counts of each tagged volume (collective)."""
    import dolfinx
    import numpy as np
    from mpi4py import MPI

    from shoulder_fem.meshes import shoulder as sh

    comm = mesh.comm
    bodies = {}
    for marker in sh.VOLUMES:
        cells = ct.indices[ct.values == marker.id]
        owned = cells[cells < n_local]
        n_cells = comm.allreduce(len(owned), op=MPI.SUM)
        if n_cells == 0:
            continue
        counts = {"cells": n_cells}
        for name, degree in (("vertices", 1), ("p2_nodes", 2)):
            space = dolfinx.fem.FunctionSpace(mesh, ("Lagrange", degree))
            flag = dolfinx.fem.Function(space)
            dofs = np.unique(
                np.concatenate([space.dofmap.cell_dofs(c) for c in cells] + [np.empty(0, np.int32)])
            )
            flag.x.array[dofs] = 1.0
            flag.x.scatter_reverse(dolfinx.la.ScatterMode.add)
            n_owned = space.dofmap.index_map.size_local
            counts[name] = comm.allreduce(int(np.count_nonzero(flag.x.array[:n_owned])))
        counts["dofs_p1"] = 3 * counts["vertices"]
        counts["dofs_displacement"] = 3 * counts["p2_nodes"]
        counts["dofs_pressure"] = counts["vertices"] if marker in sh.SOFT else 0
        bodies[marker.name] = counts
    return bodies


def _totals(mesh, bodies: dict, rigid_bone: bool) -> dict:
    """Counts of the whole mesh: cells, vertices, DOF by kind, cells by kind of body."""
    from shoulder_fem.meshes import shoulder as sh

    n_vertices = mesh.topology.index_map(0).size_global
    n_edges = mesh.topology.index_map(1).size_global
    rigid = 6 * len(sh.BONES) if rigid_bone else 0
    displacement = 3 * (n_vertices + n_edges)
    pressure = sum(b["dofs_pressure"] for b in bodies.values())
    return {
        "cells": mesh.topology.index_map(mesh.topology.dim).size_global,
        "vertices": n_vertices,
        "dofs": displacement + pressure + rigid,
        "dofs_displacement": displacement,
        "dofs_pressure": pressure,
        "dofs_rigid": rigid,
        "dofs_p1": 3 * n_vertices,
        "cells_by_kind": {
            "bone": sum(bodies.get(m.name, {}).get("cells", 0) for m in sh.BONES),
            "cartilage": sum(
                bodies.get(n, {}).get("cells", 0)
                for n in ("humeral_cartilage", "glenoid_cartilage")
            ),
            "muscle": sum(bodies.get(n, {}).get("cells", 0) for n in sh.MUSCLES),
        },
    }


#: Below this mean-ratio quality an element is reported (the tests' bound at coarse).
MIN_QUALITY = 0.02


def _quality(mesh, n_local: int) -> dict:
    """Mean-ratio quality of the tetrahedra over all ranks, and the smallest volume (m^3)."""
    import numpy as np
    from mpi4py import MPI

    comm = mesh.comm
    x = mesh.geometry.x
    cells = np.array([mesh.geometry.dofmap.links(c) for c in range(n_local)]).reshape(-1, 4)
    p = x[cells]
    e = [p[:, j] - p[:, i] for i, j in ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))]
    vol = np.abs(np.einsum("ij,ij->i", e[0], np.cross(e[1], e[2]))) / 6.0
    l_rms = np.sqrt(np.mean([np.sum(v**2, axis=1) for v in e], axis=0))
    q = 6 * np.sqrt(2) * vol / np.maximum(l_rms, 1e-30) ** 3
    q_all = np.concatenate(comm.allgather(q))
    worst = (float(q.min()), p[int(np.argmin(q))].mean(axis=0).tolist()) if len(q) else (2.0, None)
    worst_q, worst_at = min(comm.allgather(worst), key=lambda w: w[0])
    if worst_q < MIN_QUALITY and comm.rank == 0:
        logger.warning(
            "mesh: its worst element has mean-ratio quality %.3g < %g (the bound the tests "
            "require) at (%s) mm",
            worst_q,
            MIN_QUALITY,
            ", ".join(f"{1e3 * v:.1f}" for v in worst_at),
        )
    return {
        "worst_at_m": worst_at,
        "measure": "mean ratio 6 sqrt(2) V / l_rms^3 (1 = regular tetrahedron)",
        "min": float(q_all.min()),
        "q01": float(np.quantile(q_all, 0.01)),
        "median": float(np.median(q_all)),
        "min_volume_m3": float(
            comm.allreduce(float(vol.min()) if len(vol) else np.inf, op=MPI.MIN)
        ),
        "bound_checked": (
            "every volume > 0, min > 0.02, 1 % quantile > 0.05, median > 0.4 (tests, coarse)"
        ),
    }


def _facet_counts(mesh, ft) -> dict:
    """Number of facets of each tagged surface (those with any), over all ranks."""
    import numpy as np
    from mpi4py import MPI

    from shoulder_fem.meshes import shoulder as sh

    comm = mesh.comm
    facet_counts = {}
    n_facets = mesh.topology.index_map(mesh.topology.dim - 1).size_local
    for marker in sh.SURFACES:
        f = ft.indices[ft.values == marker.id]
        n = comm.allreduce(int(np.count_nonzero(f < n_facets)), op=MPI.SUM)
        if n:
            facet_counts[marker.name] = n
    return facet_counts
