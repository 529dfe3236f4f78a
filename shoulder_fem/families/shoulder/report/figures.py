"""The shoulder report's figures: the paper's Figs. 2-5 and the resources chart (PNG).

Drawn from the two runs' arrays and series and from the metrics of
:func:`~shoulder_fem.families.shoulder.report.metrics.compare_runs`; each file written atomically.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import matplotlib.tri as mtri
import numpy as np
from matplotlib.collections import PolyCollection

from shoulder_fem.families.shoulder.report.contents import (
    MPA,
    RESOURCE_COLUMNS,
    RESOURCE_LABELS,
    fmt,
)
from shoulder_fem.families.shoulder.report.data import ANGLE_TOLERANCE, RunData, angle_index
from shoulder_fem.families.shoulder.report.geometry import (
    glenoid_plane_coordinates,
    slice_tetrahedra,
)
from shoulder_fem.io.plots import METHOD_STYLE, PRINT_STYLE, save_figure

REL_ERROR_FLOOR = 0.05
"""Relative von Mises errors are drawn for the vertices above this share of the coupled maximum
(below it a small difference is a large share of a small stress)."""


def write_figures(
    runs: dict[str, RunData],
    metrics: dict[str, Any],
    pair: tuple,
    resources: dict[str, dict[str, Any]],
    out_dir: Path,
) -> dict[str, int]:
    """Draw the figures of :data:`~shoulder_fem.families.shoulder.report.contents.FIGURES`.

    Args:
        runs: the runs by method (``"coupled"``, the reference, and ``"decoupled"``).
        metrics: the metrics of the two runs (``compare_runs``).
        pair: the indices of the matched scapula vertices (coupled, decoupled).
        resources: the resources table (``resource_table``).
        out_dir: folder for the PNG files (existing).

    Returns:
        The number of polygons of the scapula's section per method.
    """
    cpl, dec = runs["coupled"], runs["decoupled"]
    _plot_pressure_maps(runs, out_dir / "pressure_maps.png")
    _plot_max_pressure(runs, out_dir / "max_pressure.png")
    _plot_muscle_forces(runs, out_dir / "muscle_forces.png")
    n_polys = _plot_section(runs, out_dir / "section_von_mises.png")
    _plot_von_mises(
        cpl,
        dec,
        metrics,
        pair,
        out_dir / "von_mises_scatter.png",
        out_dir / "von_mises_error_histogram.png",
    )
    _plot_von_mises_by_angle(metrics, out_dir / "von_mises_by_angle.png")
    _plot_resources(resources, out_dir / "resources.png")
    return n_polys


def _map_angles(runs: Sequence[RunData]) -> list[float]:
    """The columns of the pressure maps: every angle reached that is a multiple of 10 deg."""
    all_angles = sorted({round(float(a), 6) for r in runs for a in r.angles})
    tens = [a for a in all_angles if abs(a / 10.0 - round(a / 10.0)) * 10.0 < ANGLE_TOLERANCE]
    return tens or all_angles


def _glenoid_triangulation(xy: np.ndarray) -> mtri.Triangulation | None:
    """Delaunay triangulation of the projected points, long (hull-bridging) triangles masked."""
    if len(xy) < 3:
        return None
    try:
        tri = mtri.Triangulation(xy[:, 0], xy[:, 1])
    except (ValueError, RuntimeError):
        return None
    t = tri.triangles
    edges = np.stack(
        [np.linalg.norm(xy[t[:, i]] - xy[t[:, (i + 1) % 3]], axis=1) for i in range(3)], 1
    )
    long = edges.max(axis=1) > 3.0 * np.median(edges)
    # peel long triangles from the hull inwards only: no holes inside the surface
    neighbours = tri.neighbors
    mask = np.zeros(len(t), dtype=bool)
    while True:
        open_side = np.any(neighbours < 0, axis=1) | np.any(
            mask[np.where(neighbours < 0, 0, neighbours)] & (neighbours >= 0), axis=1
        )
        peel = long & open_side & ~mask
        if not peel.any():
            break
        mask |= peel
    tri.set_mask(mask)
    return tri


def _glenoid_views(runs: dict[str, RunData], angles: list[float]) -> tuple[dict, float]:
    """Each run's glenoid nodes in the glenoid's plane (mm) and the largest pressure (MPa)."""
    top = 0.0
    xy: dict[str, np.ndarray] = {}
    for m, r in runs.items():
        p = r.arrays.get("glenoid_pressure")
        for a in angles:
            i = angle_index(r.angles, a)
            if i is not None and p is not None and p.size:
                top = max(top, float(np.max(p[i])) * MPA)
        xy[m] = (
            glenoid_plane_coordinates(
                r.arrays["glenoid_points"], r.arrays["glenoid_centre"], r.arrays["glenoid_axis"]
            )
            * 1e3
        )
    return xy, top


def _plot_pressure_maps(runs: dict[str, RunData], path: Path) -> None:
    """Fig. 2: the glenoid's nodal pressure every 10 deg, both methods, on one scale.

    One colour scale in MPa for every angle and both methods (a square-root scale, so that
    the low angles' 0.05 MPa show beside 60 deg's 2 MPa), the nodal values joined linearly on
    the glenoid's triangulation (no smoothing beyond the nodes, which are dotted).
    """
    from matplotlib.colors import PowerNorm

    angles = _map_angles(list(runs.values()))
    ncols = max(len(angles), 1)
    xy, top = _glenoid_views(runs, angles)
    top = top if top > 0 else 1.0
    norm = PowerNorm(0.5, vmin=0.0, vmax=top)
    levels = np.linspace(0.0, 1.0, 21) ** 2 * top  # equal steps of the square-root scale
    levels[-1] *= 1 + 1e-9  # the maximum itself inside the top band
    cmap = plt.get_cmap("YlOrRd")
    all_xy = np.concatenate([v for v in xy.values() if len(v)] or [np.zeros((1, 2))])
    lo, hi = all_xy.min(axis=0), all_xy.max(axis=0)
    pad = 0.05 * max(float(np.max(hi - lo)), 1e-6)
    with plt.rc_context(PRINT_STYLE):
        fig, axes = plt.subplots(
            2,
            ncols,
            figsize=(min(7.0, 1.0 * ncols + 1.2), 3.4),
            squeeze=False,
            sharex=True,
            sharey=True,
            layout="constrained",
        )
        mappable = None
        for row, (m, r) in enumerate(runs.items()):
            tri = _glenoid_triangulation(xy[m])
            for col, a in enumerate(angles):
                ax = axes[row, col]
                ax.set_aspect("equal")
                ax.set_xlim(lo[0] - pad, hi[0] + pad)
                ax.set_ylim(lo[1] - pad, hi[1] + pad)
                i = angle_index(r.angles, a)
                if row == 0:
                    ax.set_title(f"{a:g}°")
                if col == 0:
                    ax.set_ylabel(f"{m}\nsuperior [mm]")
                if row == 1:
                    ax.set_xlabel("anterior [mm]")
                ax.plot(xy[m][:, 0], xy[m][:, 1], ".", ms=1.5, color="0.45")  # the nodes
                if i is None:
                    ax.text(
                        0.5,
                        0.5,
                        "not reached",
                        transform=ax.transAxes,
                        ha="center",
                        va="center",
                        color="0.4",
                    )
                    continue
                p = np.clip(r.arrays["glenoid_pressure"][i] * MPA, 0.0, None)
                ax.text(0.03, 0.03, f"max {p.max():.2g} MPa", transform=ax.transAxes, fontsize=6)
                if tri is not None:
                    mappable = ax.tricontourf(tri, p, levels=levels, cmap=cmap, norm=norm)
                else:
                    mappable = ax.scatter(xy[m][:, 0], xy[m][:, 1], c=p, s=6, cmap=cmap, norm=norm)
        if mappable is not None:
            bar = fig.colorbar(mappable, ax=axes, shrink=0.85)
            bar.set_label("contact pressure [MPa] (square-root scale)")
            bar.set_ticks([t for t in (0, 0.01, 0.05, 0.1, 0.25, 0.5, 1, 2, 4, 8) if t <= top])
        fig.suptitle(
            "Glenoid contact pressure, viewed along the glenoid axis: the nodal values (dots), "
            "joined linearly"
        )
        save_figure(fig, path, vector=True)


def _plot_max_pressure(runs: dict[str, RunData], path: Path) -> None:
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for m, r in runs.items():
        a = r.angles
        ax.plot(a, r.max_pressure(a) * MPA, marker="o", ms=4, label=m, **METHOD_STYLE.get(m, {}))
    ax.set_xlabel("humeral internal rotation (deg)")
    ax.set_ylabel("maximum glenoid pressure (MPa)")
    ax.set_title("Maximum glenoid contact pressure")
    ax.grid(alpha=0.3)
    ax.legend()
    save_figure(fig, path, vector=True)


def _plot_muscle_forces(runs: dict[str, RunData], path: Path) -> None:
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    colours = {"infraspinatus": "C0", "subscapularis": "C1", "supraspinatus": "C2"}
    for muscle, colour in colours.items():
        alpha = 0.45 if muscle == "supraspinatus" else 1.0
        for m, r in runs.items():
            ser = r.summary.get("series", {}).get(f"{muscle}_force")
            if not ser:
                continue
            ls = "-" if m == "coupled" else "--"
            marker = "o" if m == "coupled" else "s"
            ax.plot(
                ser["x"],
                ser["y"],
                ls=ls,
                marker=marker,
                ms=4,
                color=colour,
                alpha=alpha,
                mfc="none" if m != "coupled" else colour,
                label=f"{muscle} ({m})",
            )
    ax.set_xlabel("humeral internal rotation (deg)")
    ax.set_ylabel("muscle force (N)")
    ax.set_title("Muscle forces at the scapular footprints")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, ncol=2)
    save_figure(fig, path, vector=True)


def _plot_section(runs: dict[str, RunData], path: Path) -> dict[str, int]:
    """Fig. 4; returns the number of section polygons per run."""
    sections = {}
    vmax = 0.0
    for m, r in runs.items():
        z = float(r.arrays.get("section_z", math.nan))
        polys, vals = (
            slice_tetrahedra(
                r.arrays["scapula_points"],
                r.arrays["scapula_cells"],
                r.arrays["scapula_von_mises"],
                z,
            )
            if math.isfinite(z)
            else ([], [])
        )
        face = np.array([float(np.mean(v)) for v in vals]) * MPA
        sections[m] = ([p * 1e3 for p in polys], face, z)
        if len(face):
            vmax = max(vmax, float(face.max()))
    vmax = vmax if vmax > 0 else 1.0
    # one panel per run, stacked: the blade's section is long and thin
    bounds = [p for s in sections.values() for p in s[0]]
    aspect = 0.3
    if bounds:
        allp = np.concatenate(bounds)
        span = np.ptp(allp[:, :2], axis=0)
        aspect = float(np.clip(span[1] / max(span[0], 1e-9), 0.1, 1.0))
    fig, axes = plt.subplots(
        len(runs), 1, figsize=(9.0, len(runs) * (7.0 * aspect + 0.9) + 0.8), squeeze=False
    )
    axes = axes.T
    coll = None
    for ax, (m, (polys, face, z)) in zip(axes[0], sections.items(), strict=True):
        r = runs[m]
        z_mm = round(z * 1e3, 1) + 0.0  # + 0.0: never "-0.0"
        ax.set_title(f"{m}: {fmt(r.von_mises_angle, 'g')}°, z = {z_mm:.1f} mm")
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
        ax.set_aspect("equal")
        if not polys:
            ax.text(
                0.5,
                0.5,
                "the plane misses the scapula",
                transform=ax.transAxes,
                ha="center",
                va="center",
            )
            continue
        coll = PolyCollection(polys, array=face, cmap="viridis", edgecolors="face", linewidths=0.2)
        coll.set_clim(0.0, vmax)
        ax.add_collection(coll)
        allp = np.concatenate(bounds)
        ax.set_xlim(allp[:, 0].min(), allp[:, 0].max())
        ax.set_ylim(allp[:, 1].min(), allp[:, 1].max())
    if coll is not None:
        fig.colorbar(coll, ax=axes[0].tolist(), shrink=0.9, label="von Mises stress (MPa)")
    fig.suptitle("Von Mises stress in the horizontal section of the scapula")
    save_figure(fig, path, vector=True)
    return {m: len(s[0]) for m, s in sections.items()}


def _plot_von_mises(
    cpl: RunData, dec: RunData, metrics: dict, pair: tuple, scatter: Path, hist: Path
) -> None:
    i_c, i_d = pair
    c = np.asarray(cpl.arrays["scapula_von_mises"], dtype=float)[i_c] * MPA
    d = np.asarray(dec.arrays["scapula_von_mises"], dtype=float)[i_d] * MPA
    note = metrics.get("von_mises_note")
    a_c, a_d = fmt(cpl.von_mises_angle, "g"), fmt(dec.von_mises_angle, "g")
    angles = f"coupled {a_c}°, decoupled {a_d}°"

    fig, ax = plt.subplots(figsize=(5.4, 5.0))
    ax.plot(c, d, ".", ms=3, alpha=0.5, color="C0", label=f"{len(c)} scapula vertices")
    top = max(float(c.max()) if len(c) else 0.0, float(d.max()) if len(d) else 0.0, 1e-12)
    ax.plot([0, top], [0, top], color="k", lw=0.8, label="y = x")
    slope, corr = metrics.get("von_mises_slope"), metrics.get("von_mises_correlation")
    if slope is not None:
        ax.plot(
            [0, top],
            [0, slope * top],
            color="C3",
            lw=1.0,
            ls="--",
            label=f"least squares: slope {slope:.4f}, r = {fmt(corr, '.4f')}",
        )
    ax.set_xlim(0, top * 1.03)
    ax.set_ylim(0, top * 1.03)
    ax.set_aspect("equal")
    ax.set_xlabel("von Mises, coupled (MPa)")
    ax.set_ylabel("von Mises, decoupled (MPa)")
    ax.set_title(f"Nodal von Mises stress ({angles})" + (f"\n{note}" if note else ""), fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left")
    save_figure(fig, scatter, vector=True)
    _plot_von_mises_histogram(c, d, angles, note, hist)


def _plot_von_mises_histogram(c: np.ndarray, d: np.ndarray, angles: str, note, hist: Path) -> None:
    """The differences (MPa) and the paper's Fig. 5b (share of the nodes per relative error)."""
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(11.0, 4.0))
    diff = d - c
    cmax = float(np.max(np.abs(c))) if len(c) else 0.0
    if len(diff):
        _histogram(ax, diff, "C0", f"mean {diff.mean():.3g} MPa, std {diff.std():.3g} MPa")
    ax.axvline(0.0, color="k", lw=0.8)
    ax.set_xlabel("von Mises, decoupled − coupled (MPa)")
    ax.set_ylabel("vertices")
    if cmax > 0:
        sec = ax.secondary_xaxis(
            "top", functions=(lambda x: 100.0 * x / cmax, lambda x: x * cmax / 100.0)
        )
        sec.set_xlabel("% of the coupled maximum")
    ax.grid(alpha=0.3)
    # the paper's Fig. 5b: the share of the nodes with a given relative error
    loaded = np.abs(c) >= REL_ERROR_FLOOR * cmax if cmax > 0 else np.zeros(len(c), dtype=bool)
    if np.any(loaded):
        rel = 100.0 * diff[loaded] / c[loaded]
        label = f"mean {rel.mean():+.2f} %, std {rel.std():.2f} %"
        _histogram(ax2, rel, "C2", label, weights=np.full(len(rel), 100.0 / len(rel)))
    ax2.axvline(0.0, color="k", lw=0.8)
    ax2.set_xlabel("relative error, (decoupled − coupled) / coupled (%)")
    ax2.set_ylabel("% of the vertices")
    ax2.set_title(
        f"{int(np.sum(loaded))} vertices above {100 * REL_ERROR_FLOOR:g} % of the coupled maximum",
        fontsize=9,
    )
    ax2.grid(alpha=0.3)
    fig.suptitle(
        f"Nodal von Mises differences ({angles})" + (f"\n{note}" if note else ""), fontsize=9
    )
    fig.tight_layout()
    save_figure(fig, hist, vector=True)


def _histogram(ax, values: np.ndarray, colour: str, label: str, weights=None) -> None:
    """60 bins of ``values`` with their legend."""
    ax.hist(values, bins=60, weights=weights, color=colour, alpha=0.8, label=label)
    ax.legend(fontsize=8)


def _plot_von_mises_by_angle(metrics: dict[str, Any], path: Path) -> None:
    """Slope and largest difference of the nodal von Mises stress against the angle."""
    rows = metrics.get("von_mises_per_angle") or []
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(10.0, 3.8))
    for key, label, colour in (
        ("scapula", "whole scapula", "C0"),
        ("glenoid_region", "glenoid region", "C3"),
    ):
        a = [r["angle_deg"] for r in rows]
        slope = [r[key]["slope"] if r[key]["slope"] is not None else np.nan for r in rows]
        err = [
            100 * r[key]["max_error_of_max"] if r[key]["max_error_of_max"] is not None else np.nan
            for r in rows
        ]
        ax.plot(a, slope, "o-", color=colour, label=label)
        ax2.plot(a, err, "o-", color=colour, label=label)
    ax.axhspan(0.98, 1.02, color="0.9", label="paper's criterion 0.98-1.02")
    ax.set_xlabel("internal rotation (deg)")
    ax.set_ylabel("von Mises slope, decoupled / coupled")
    ax2.set_xlabel("internal rotation (deg)")
    ax2.set_ylabel("largest difference (% of the region's max)")
    for axis in (ax, ax2):
        axis.grid(alpha=0.3)
        axis.legend(fontsize=8)
    if not rows:
        ax.set_title("no von Mises series in these runs", fontsize=9)
    fig.suptitle("Nodal von Mises stress at every output angle, decoupled against coupled")
    fig.tight_layout()
    save_figure(fig, path, vector=True)


def _plot_resources(table: dict[str, dict[str, Any]], path: Path) -> None:
    labels = [RESOURCE_LABELS[k].replace(" ", "\n", 1) for k in RESOURCE_COLUMNS]
    colours = ["C0", "#f4a3a0", "#f4a3a0", "C3"]
    fig, axes = plt.subplots(1, 3, figsize=(12.0, 3.8))
    for ax, (key, name) in zip(
        axes,
        (
            ("cpu_s", "CPU time (s)"),
            ("peak_rss_mb", "peak memory (MB)"),
            ("results_disk_mb", "results disk (MB)"),
        ),
        strict=True,
    ):
        vals = [table[k].get(key) for k in RESOURCE_COLUMNS]
        x = np.arange(len(vals))
        heights = [v if isinstance(v, int | float) and math.isfinite(v) else 0.0 for v in vals]
        bars = ax.bar(x, heights, color=colours)
        for bar, v in zip(bars, vals, strict=True):
            ok = isinstance(v, int | float) and math.isfinite(v)
            text = (fmt(v, ".0f" if abs(v) >= 100 else ".3g")) if ok else "n/a"
            ax.annotate(
                text,
                (bar.get_x() + bar.get_width() / 2, bar.get_height()),
                ha="center",
                va="bottom",
                fontsize=8,
                xytext=(0, 2),
                textcoords="offset points",
            )
        ax.set_xticks(x, labels, fontsize=8)
        ax.set_ylabel(name)
        ax.grid(axis="y", alpha=0.3)
        ax.margins(y=0.15)
    fig.suptitle("Resources (sums over ranks; part figures are the stages of the decoupled run)")
    fig.tight_layout()
    save_figure(fig, path, vector=True)
