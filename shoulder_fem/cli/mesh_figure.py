"""``mesh.png`` of the ``mesh`` command: the bodies' surfaces in 3D and density slices.

The figure is drawn on rank 0 from the surface triangles of every rank; the backend is the
caller's (the command line selects Agg).
"""

from __future__ import annotations

from pathlib import Path

COLOURS = {
    "humerus": "#d9c27a",
    "scapula": "#b5835a",
    "humeral_cartilage": "#4fa3e0",
    "glenoid_cartilage": "#1f4fbf",
    "subscapularis": "#d62728",
    "supraspinatus": "#ff7f0e",
    "infraspinatus": "#c2185b",
}
"""Face colour of each body in the 3D views."""


def plot_mesh(comm, path: Path, sm, image, calibration) -> None:
    """mesh.png: body surfaces in 3D, and a density slice through the joint (rank 0 draws).

    Args:
        comm: the mesh's communicator (collective: every rank sends its triangles).
        path: the PNG file.
        sm: the shoulder mesh (``meshes.shoulder.ShoulderMesh``).
        image: the CT image (:class:`shoulder_fem.io.ct.CTImage`) the density comes from.
        calibration: its HU calibration (:class:`shoulder_fem.io.ct.Calibration`).
    """
    import numpy as np

    tris, body = _surface_triangles(sm)
    tris = comm.gather(np.array(tris).reshape(-1, 3, 3), root=0)
    body = comm.gather(np.array(body, dtype=np.int32), root=0)
    if comm.rank != 0:
        return
    import matplotlib.pyplot as plt

    tris, body = np.concatenate(tris) * 1e3, np.concatenate(body)
    lo, hi = tris.reshape(-1, 3).min(axis=0), tris.reshape(-1, 3).max(axis=0)
    fig = plt.figure(figsize=(16, 10))
    _draw_views(fig, tris, body, lo, hi)
    _draw_density_slices(fig, image, calibration, lo, hi)
    fig.suptitle(
        "shoulder mesh: bones, cartilages, muscles (outer and bonded-interface faces); density "
        "from the CT image, rho = a + b HU",
        fontsize=11,
    )
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _surface_triangles(sm) -> tuple[list, list]:
    """This rank's outer and body-interface triangles (m) and the volume tag of each.

    In the rigid-bone variant also the kept bone surfaces, tagged humerus or scapula.
    """
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
    return tris, body


def _draw_views(fig, tris, body, lo, hi) -> None:
    """The three 3D views (top row): the whole model from two sides, and the joint (mm)."""
    import numpy as np
    from matplotlib.ticker import MaxNLocator
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    from shoulder_fem.meshes import shoulder as sh

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
        ax.yaxis.set_major_locator(MaxNLocator(nbins=3))  # the short axis: labels overlapped
        ax.set_title(title, fontsize=10)
        if k == 0:  # beside the first view, not over it
            ax.legend(loc="upper right", fontsize=7, bbox_to_anchor=(0.02, 1.0))


def _draw_density_slices(fig, image, calibration, lo, hi) -> None:
    """The two density slices (bottom row) sampled from the image, and their colour bar.

    Transverse (z = 0, the contact level) and scapular plane (y = 0); axes in mm.
    """
    import numpy as np

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
