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

from shoulder_fem.cli.args import add_scene_arguments

logger = logging.getLogger(__name__)

ELEMENT = {
    "cell": "straight-sided tetrahedron",
    "bone": "P2 displacement (compressible, nu = 0.3)",
    "cartilage_and_muscle": (
        "Taylor-Hood P2/P1: P2 displacement, continuous P1 pressure per body (inf-sup stable, "
        "no volumetric locking of the nearly incompressible tissue)"
    ),
    "dof_count": (
        "dofs = dofs_displacement (3 x P2 nodes of the mesh) + dofs_pressure (P1 vertices of "
        "each soft body) + 6 per rigid bone (rigid-bone variant); dofs_p1 = 3 x vertices is "
        "the count of a linear element, for comparison with the paper's 8-node hexahedra"
    ),
}

COLOURS = {
    "humerus": "#d9c27a",
    "scapula": "#b5835a",
    "humeral_cartilage": "#4fa3e0",
    "glenoid_cartilage": "#1f4fbf",
    "subscapularis": "#d62728",
    "supraspinatus": "#ff7f0e",
    "infraspinatus": "#c2185b",
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
    p.add_argument("--out", type=Path, required=True, help="output folder (written atomically)")
    return p


def cmd_mesh(args) -> int:
    """Build, measure and write the mesh of a shoulder scene; returns the exit status (0)."""
    import numpy as np
    from mpi4py import MPI

    from shoulder_fem.io import ct as dens
    from shoulder_fem.io.output import OutputDir, atomic_write_json
    from shoulder_fem.meshes import shoulder as sh
    from shoulder_fem.scene import SceneError, load_scene

    comm = MPI.COMM_WORLD
    t0 = time.perf_counter()
    scene = load_scene(args.scene).with_overrides(list(args.sets))
    if scene.family != "shoulder":
        raise SceneError(
            f"{scene.source}: scene '{scene.name}' is of family '{scene.family}'; "
            "the mesh command builds 'shoulder' scenes"
        )
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
    calibration = dens.Calibration()
    if args.ct is not None:
        try:
            image = dens.read_ct(args.ct)
        except (OSError, ValueError) as err:
            raise SceneError(f"--ct {args.ct}: {err}") from None
    out = OutputDir(args.out, comm)
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
        rho, modulus = dens.nodal_modulus(sm.mesh, image, calibration)
        _write_density(comm, out.path / "density.xdmf", sm.mesh, rho, modulus)
        stats = mesh_statistics(sm)
        summary = {
            "scene": scene.name,
            "command": "mesh",
            "level": level,
            "variant": args.variant,
            "parameters": {
                k: {"value": p.value, "unit": p.unit} for k, p in scene.parameters.items()
            },
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
            "timing": {
                "geometry_s": sm.info.get("geometry_s"),
                "meshing_s": sm.info.get("meshing_s"),
                "gmsh_s": sm.info.get("build_s"),
                "mesh_total_s": t_mesh,
                "wall_s": time.perf_counter() - t0,
            },
            "ranks": comm.size,
        }
        _plot(comm, out.path / "mesh.png", sm, image, calibration)
        summary["timing"]["wall_s"] = time.perf_counter() - t0
        if comm.rank == 0:
            atomic_write_json(out.path / "mesh.json", summary)
        comm.Barrier()
        del np
    if comm.rank == 0:
        tot = stats["totals"]
        print(
            f"mesh: {level} {args.variant}: {tot['cells']} cells, {tot['dofs']} DOF "
            f"({tot['dofs_displacement']} P2 displacement + {tot['dofs_pressure']} P1 pressure"
            f"{' + 12 rigid' if args.variant == 'rigid-bone' else ''}), gmsh "
            f"{summary['timing']['gmsh_s']:.1f} s (geometry {summary['timing']['geometry_s']:.1f}"
            f" s, meshing {summary['timing']['meshing_s']:.1f} s) -> {out.final}",
            flush=True,
        )
    return 0


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
    import dolfinx
    import numpy as np
    from mpi4py import MPI

    from shoulder_fem.meshes import shoulder as sh

    mesh, ct = sm.mesh, sm.cell_tags
    comm = mesh.comm
    tdim = mesh.topology.dim
    mesh.topology.create_entities(1)
    n_local = mesh.topology.index_map(tdim).size_local
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
    n_vertices = mesh.topology.index_map(0).size_global
    n_edges = mesh.topology.index_map(1).size_global
    rigid = 6 * len(sh.BONES) if sm.bone_surface is not None else 0
    displacement = 3 * (n_vertices + n_edges)
    pressure = sum(b["dofs_pressure"] for b in bodies.values())
    totals = {
        "cells": mesh.topology.index_map(tdim).size_global,
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
    x = mesh.geometry.x
    cells = np.array([mesh.geometry.dofmap.links(c) for c in range(n_local)]).reshape(-1, 4)
    p = x[cells]
    e = [p[:, j] - p[:, i] for i, j in ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))]
    vol = np.abs(np.einsum("ij,ij->i", e[0], np.cross(e[1], e[2]))) / 6.0
    l_rms = np.sqrt(np.mean([np.sum(v**2, axis=1) for v in e], axis=0))
    q = 6 * np.sqrt(2) * vol / np.maximum(l_rms, 1e-30) ** 3
    q_all = np.concatenate(comm.allgather(q))
    quality = {
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
    facet_counts = {}
    ft = sm.facet_tags
    n_facets = mesh.topology.index_map(tdim - 1).size_local
    for marker in sh.SURFACES:
        f = ft.indices[ft.values == marker.id]
        n = comm.allreduce(int(np.count_nonzero(f < n_facets)), op=MPI.SUM)
        if n:
            facet_counts[marker.name] = n
    return {"bodies": bodies, "totals": totals, "quality": quality, "facets": facet_counts}


def _plot(comm, path: Path, sm, image, calibration) -> None:
    """mesh.png: body surfaces in 3D, and a density slice through the joint (rank 0 draws)."""
    import numpy as np

    from shoulder_fem.meshes import shoulder as sh

    mesh, ct = sm.mesh, sm.cell_tags
    tdim = mesh.topology.dim
    mesh.topology.create_connectivity(tdim - 1, tdim)
    mesh.topology.create_connectivity(tdim - 1, 0)
    f_to_c = mesh.topology.connectivity(tdim - 1, tdim)
    c_to_v = mesh.topology.connectivity(tdim, 0)
    n_cells = mesh.topology.index_map(tdim).size_local + mesh.topology.index_map(tdim).num_ghosts
    tag = np.zeros(n_cells, dtype=np.int32)
    tag[ct.indices] = ct.values
    n_vert = mesh.topology.index_map(0).size_local + mesh.topology.index_map(0).num_ghosts
    v_to_x = np.zeros(n_vert, dtype=np.int64)
    for c in range(n_cells):
        v_to_x[c_to_v.links(c)] = mesh.geometry.dofmap.links(c)
    f_to_v = mesh.topology.connectivity(tdim - 1, 0)
    tris, body = [], []
    for f in range(mesh.topology.index_map(tdim - 1).size_local):
        cells = f_to_c.links(f)
        tags = set(tag[cells])
        if len(cells) == 1 or len(tags) == 2:
            for t in tags:
                tris.append(mesh.geometry.x[v_to_x[f_to_v.links(f)]])
                body.append(t)
    if sm.bone_surface is not None:  # rigid-bone: the kept bone surfaces, coloured by bone
        surf, stags = sm.bone_surface, sm.bone_surface_tags
        humeral = {
            m.id
            for m in sh.RIGID_BONE_SURFACES
            if m.name.startswith(("humer", "humeral")) or m.name.endswith("_insertion")
        }
        n_local = surf.topology.index_map(2).size_local
        for c, value in zip(stags.indices, stags.values, strict=True):
            if c < n_local:
                tris.append(surf.geometry.x[surf.geometry.dofmap.links(c)])
                body.append(sh.HUMERUS.id if value in humeral else sh.SCAPULA.id)
    tris = comm.gather(np.array(tris).reshape(-1, 3, 3), root=0)
    body = comm.gather(np.array(body, dtype=np.int32), root=0)
    if comm.rank != 0:
        return
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    tris, body = np.concatenate(tris) * 1e3, np.concatenate(body)
    lo, hi = tris.reshape(-1, 3).min(axis=0), tris.reshape(-1, 3).max(axis=0)
    fig = plt.figure(figsize=(16, 10))
    views = (
        ("posterior-lateral view", 20, -60, None),
        ("anterior view", 20, 120, None),
        ("the joint from anterior: cartilages, bone within 35 mm", 10, 80, 35.0),
    )
    for k, (title, elev, azim, radius) in enumerate(views):
        ax = fig.add_subplot(2, 3, k + 1, projection="3d")
        for marker in sh.VOLUMES:
            sel = tris[body == marker.id]
            if radius is not None:
                if marker.name in sh.MUSCLES:
                    continue
                sel = sel[np.linalg.norm(sel.mean(axis=1), axis=1) < radius]
            if len(sel) == 0:
                continue
            ax.add_collection3d(
                Poly3DCollection(
                    sel, facecolor=COLOURS[marker.name], edgecolor="k", linewidths=0.05
                )
            )
            if k == 0:
                ax.plot([], [], color=COLOURS[marker.name], lw=6, label=marker.name)
        a, b = (lo, hi) if radius is None else (-np.full(3, radius), np.full(3, radius))
        ax.set_xlim(a[0], b[0])
        ax.set_ylim(a[1], b[1])
        ax.set_zlim(a[2], b[2])
        ax.set_box_aspect(b - a)
        ax.view_init(elev=elev, azim=azim)
        ax.set_xlabel("x lateral (mm)", fontsize=8)
        ax.set_ylabel("y anterior (mm)", fontsize=8)
        ax.set_zlabel("z superior (mm)", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.set_title(title, fontsize=10)
        if k == 0:
            ax.legend(loc="upper left", fontsize=7, bbox_to_anchor=(-0.1, 1.0))
    # Density slices from the image: transverse (z = 0, the contact level) and scapular plane
    # (y = 0).
    from shoulder_fem.io import ct as dens

    for k, (title, axis_name, span) in enumerate(
        (
            ("density, transverse slice z = 0 (contact level)", "y anterior (mm)", (-45.0, 45.0)),
            ("density, scapular-plane slice y = 0", "z superior (mm)", (lo[2], hi[2])),
        )
    ):
        ax2 = fig.add_subplot(2, 2, 3 + k)
        xs = np.linspace(lo[0], hi[0], 500)
        vs = np.linspace(span[0], span[1], 300)
        gx, gv = np.meshgrid(xs, vs, indexing="xy")
        zero = np.zeros(gx.size)
        pts = np.c_[gx.ravel(), gv.ravel(), zero] if k == 0 else np.c_[gx.ravel(), zero, gv.ravel()]
        rho = dens.nodal_density(image, pts * 1e-3, calibration).reshape(gx.shape)
        im = ax2.imshow(
            rho / 1e3,
            origin="lower",
            extent=[xs[0], xs[-1], vs[0], vs[-1]],
            cmap="bone",
            vmin=0.2,
            vmax=1.9,
        )
        ax2.set_title(title, fontsize=10)
        ax2.set_xlabel("x lateral (mm)")
        ax2.set_ylabel(axis_name)
        ax2.set_aspect("equal")
    fig.colorbar(im, ax=fig.axes[-2:], shrink=0.8, label="apparent density (g/cm$^3$)")
    fig.suptitle(
        "shoulder mesh: bones, cartilages, muscles (outer and bonded-interface faces); density "
        "from the CT image, rho = a + b HU",
        fontsize=11,
    )
    fig.savefig(path, dpi=100)
    plt.close(fig)
