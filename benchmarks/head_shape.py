"""Benchmark: the head-shape study the paper was written for (issue 21, item 3).

    OMP_NUM_THREADS=1 python benchmarks/head_shape.py --level medium --out benchmarks/results

How does the humeral head's shape change the stress in the scapula? The anatomical head (a
sphere of 24 mm, its cartilage to 70 deg) against prosthetic heads (``head_shape = prosthetic``)
over the range this glenoid (26.3 mm) and the mesh builder allow: implant radius 22 to 25.5 mm
(the anatomical head's 24 mm -2/+1.5 mm; a larger implant buries the anatomical tuberosities,
and 20 mm fails in gmsh) at the anatomical offsets, and the implant centre moved 2 mm medially,
1.5 mm laterally (2 mm aborts gmsh 4.8 at ``medium``: an exception inside its parallel surface
mesher, which no caller can catch), 2 mm anteriorly and posteriorly at 24 mm. Each implant's
cartilage ends on the anatomical neck plane (:meth:`ShoulderGeometry.neck_plane_cap_angle`:
where the surgeon cuts), so a smaller head covers a smaller arc.

Every shape runs the decoupled method (with its own part 1, since part 1 sees the head) to
60 deg; the coupled method runs on ``--check`` shapes (the anatomical head and the smallest
implant by default) and each is compared with its decoupled run by the study's report (the
paper's criteria). Per shape: the peak contact pressure, the muscle forces, the scapula's
largest nodal von Mises stress over the whole bone and within 20 mm of the glenoid's centre
(``GLENOID_REGION``),
the contact path on the glenoid (pressure-weighted centre of the contact, mm anterior and
superior of the glenoid's centre), the contact's margin to the humeral cartilage's edge, the
swing, the transferred loads' equilibrium with the springs, and the CPU time, memory and Newton
iterations of each method, i.e. what the study costs with each. Writes ``head_shape.json`` and
``head_shape.png``; the checked shapes' reports in ``head_shape_reports/<shape>/``. Every figure
is measured; it asserts nothing.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import tempfile
from pathlib import Path

import matplotlib
import numpy as np

from shoulder_fem import load_scene, run
from shoulder_fem.api import Result, RunFailed
from shoulder_fem.families.shoulder.report.metrics import GLENOID_REGION
from shoulder_fem.families.shoulder.report.writer import write_report
from shoulder_fem.families.shoulder.sweep import glenoid_von_mises
from shoulder_fem.io.output import atomic_write_json
from shoulder_fem.io.plots import plt, save_figure
from shoulder_fem.meshes.shoulder import geometry_from_values

SCENE = "shoulder-internal-rotation"
IMPLANT = ["head_shape=prosthetic"]
SHAPES = {
    "anatomical": [],
    "implant R22": [*IMPLANT, "prosthesis_radius=22mm"],
    "implant R23": [*IMPLANT, "prosthesis_radius=23mm"],
    "implant R24": IMPLANT,
    "implant R25": [*IMPLANT, "prosthesis_radius=25mm"],
    "implant R25.5": [*IMPLANT, "prosthesis_radius=25.5mm"],
    "medial +2": [*IMPLANT, "prosthesis_offset_medial=9mm"],
    "medial -1.5": [*IMPLANT, "prosthesis_offset_medial=5.5mm"],
    "posterior +2": [*IMPLANT, "prosthesis_offset_posterior=2mm"],
    "posterior -2": [*IMPLANT, "prosthesis_offset_posterior=-2mm"],
}
MUSCLES = ("subscapularis", "infraspinatus", "supraspinatus")
#: The figure's first row: before the contact reaches the humeral cartilage's edge in most
#: shapes (it does from 30-40 deg, issue 20 item 4); the second row is at the last angle.
EARLY_ANGLE = 30.0
SERIES = (
    "max_pressure",
    "contact_force",
    *(f"{m}_force" for m in MUSCLES),
    "scapula_max_von_mises",
    "humeral_swing",
    "humeral_cap_edge_margin",
    "transfer_equilibrium_residual",
)


def shape_overrides(name: str) -> list[str]:
    """The shape's ``--set`` list, the implant's cartilage ending on the anatomical neck plane."""
    overrides = list(SHAPES[name])
    scene = load_scene(SCENE).with_overrides(overrides)
    if "head_shape=prosthetic" in overrides:
        angle = geometry_from_values(scene.values()).neck_plane_cap_angle()
        overrides.append(f"humeral_cartilage_angle={math.degrees(angle):.4f}deg")
    return overrides


def slug(name: str) -> str:
    """A shape's name as a folder name."""
    return name.replace(" ", "_").replace("+", "p").replace("-", "m")


def contact_path(folder: Path) -> dict:
    """Pressure-weighted centre of the glenoid's contact at every output angle (mm).

    In the glenoid's plane, from its centre: ``anterior`` and ``superior`` (the scapular frame's
    y and z, made normal to the glenoid's axis).
    """
    with np.load(folder / "shoulder.npz") as a:
        X, p = a["glenoid_points"], np.clip(a["glenoid_pressure"], 0.0, None)
        centre, axis, angles = a["glenoid_centre"], a["glenoid_axis"], a["angles_deg"]
    sup = np.array([0.0, 0.0, 1.0]) - axis[2] * axis
    sup /= np.linalg.norm(sup)
    ant = np.cross(sup, axis)
    out = {"angles_deg": [float(a) for a in angles], "anterior_mm": [], "superior_mm": []}
    for row in p:
        c = (row @ X) / row.sum() - centre if row.sum() > 0 else np.full(3, np.nan)
        out["anterior_mm"].append(float(c @ ant) * 1e3)
        out["superior_mm"].append(float(c @ sup) * 1e3)
    return out


def one(level: str, overrides: list[str], method: str, out: Path) -> dict:
    """One run: its status, counters, cost, series, contact path and glenoid von Mises."""
    scene = load_scene(SCENE).with_overrides(overrides)
    if (out / "summary.json").is_file():  # finished in an earlier invocation (--runs)
        r = Result.load(out)
        _check_reused(r, scene, level, method)
    else:
        try:
            r = run(scene, method, level=level, out=out)
        except RunFailed as err:  # the steps before the failure are in the folder
            r = err.summary
    p, stages = r.probes, {s["name"]: s.get("cpu_s") for s in r.stages}
    row = {
        "status": r.status,
        "message": r.message,
        "final_angle_deg": p["final_angle_deg"],
        "steps": p["steps"],
        "failed_steps": p["failed_steps"],
        "newton_iterations": p["newton_iterations"],
        "cap_half_angle_deg": p["humeral_cap_half_angle_deg"],
        "cpu_s": r.resources["cpu_s"],
        "wall_s": r.resources["wall_s"],
        "peak_rss_mb": r.resources["peak_rss_mb"],
        "stage_cpu_s": stages,
        "dofs": r.data.get("dofs"),
        "series": {
            k: {"x": r.series[k]["x"], "y": r.series[k]["y"]} for k in SERIES if k in r.series
        },
    }
    if (out / "shoulder.npz").exists():
        row["contact_path"] = contact_path(out)
        row["glenoid_von_mises_mpa"] = glenoid_von_mises(out)
    return row


def _check_reused(r: Result, scene, level: str, method: str) -> None:
    """A reused run folder must be this shape's run: same method, level and parameters."""
    wanted = scene.values()
    recorded = r.parameters
    differ = [
        k
        for k, v in wanted.items()
        if k in recorded
        and isinstance(v, float)
        and not math.isclose(float(recorded[k]), v, rel_tol=1e-9, abs_tol=1e-12)
    ]
    if r.method != method or r.level != level or differ:
        raise SystemExit(
            f"{r.folder}: holds a {r.method} run at {r.level} (wanted: {method} at {level}; "
            f"parameters that differ: {', '.join(differ) or 'none'}); remove it or choose "
            "another --runs folder"
        )


def check(runs: dict, level: str, out: Path) -> dict:
    """The coupled run against the decoupled one by the study's report (paper's criteria)."""
    report = write_report(runs["coupled"], runs["decoupled"], out, level)
    per_angle = report.get("von_mises_per_angle") or []

    def span(region: str, key: str) -> list[float] | None:
        v = [a[region][key] for a in per_angle if a[region].get(key) is not None]
        return [min(v), max(v)] if v else None

    return {
        "max_pressure_rel_error": report.get("max_pressure_rel_error"),
        "muscle_force_rel_error": report.get("muscle_force_rel_error"),
        "contact_region_jaccard_min": report.get("contact_region_jaccard_min"),
        "von_mises_scapula_correlation": span("scapula", "correlation"),
        "von_mises_scapula_slope": span("scapula", "slope"),
        "von_mises_glenoid_correlation": span("glenoid_region", "correlation"),
        "von_mises_glenoid_slope": span("glenoid_region", "slope"),
        "speedup_cpu": report.get("speedup_cpu"),
    }


def _at(series: dict, key: str, angle: float, scale: float = 1.0) -> float:
    """A series' value at ``angle`` (NaN if the run did not reach it)."""
    s = series.get(key)
    i = _index(s["x"], angle) if s else None
    return math.nan if i is None or s["y"][i] is None else s["y"][i] * scale


def _index(angles: list[float], angle: float) -> int | None:
    """Position of ``angle`` among the output ``angles`` (None if not reached)."""
    hits = [i for i, a in enumerate(angles) if abs(a - angle) < 1e-6]
    return hits[0] if hits else None


def common_angle(data: dict) -> float:
    """The largest output angle every shape's decoupled run reached (deg)."""
    reached = [
        max(e["runs"]["decoupled"].get("contact_path", {}).get("angles_deg", [0.0]))
        for e in data["shapes"].values()
    ]
    return float(min(reached))


def _shape_panels(axes, data: dict, names: list[str], angle: float) -> None:
    """Glenoid von Mises, peak pressure and muscle forces at ``angle`` against the shape."""
    x = np.arange(len(names))
    for method, marker in (("decoupled", "o"), ("coupled", "x")):
        have = [i for i, n in enumerate(names) if method in data["shapes"][n]["runs"]]
        if not have:
            continue
        runs = [data["shapes"][names[i]]["runs"][method] for i in have]
        j = [_index(r.get("contact_path", {}).get("angles_deg", []), angle) for r in runs]
        gv = [
            r["glenoid_von_mises_mpa"][k] if k is not None else np.nan
            for r, k in zip(runs, j, strict=True)
        ]
        sv = [_at(r["series"], "scapula_max_von_mises", angle, 1e-6) for r in runs]
        axes[0].plot(x[have], gv, marker, color="C3", label=f"glenoid region, {method}")
        axes[0].plot(x[have], sv, marker, color="C0", label=f"whole scapula, {method}")
        pv = [_at(r["series"], "max_pressure", angle, 1e-6) for r in runs]
        axes[1].plot(x[have], pv, marker, color="C1", label=method)
        for c, m in enumerate(MUSCLES):
            mv = [_at(r["series"], f"{m}_force", angle) for r in runs]
            axes[2].plot(x[have], mv, marker, color=f"C{c + 4}", label=f"{m}, {method}")
    margins = [
        _at(data["shapes"][n]["runs"]["decoupled"]["series"], "humeral_cap_edge_margin", angle)
        for n in names
    ]
    at_edge = sum(m < 1.0 for m in margins)  # deg: the contact on the cartilage's edge
    where = f"{angle:g} deg (on the cap's edge: {at_edge} of {len(names)} shapes)"
    titles = (
        f"largest nodal von Mises (MPa), {where}",
        f"peak glenoid pressure (MPa), {where}",
        f"muscle forces (N), {angle:g} deg",
    )
    for ax, title in zip(axes, titles, strict=True):
        ax.set_xticks(x, names, rotation=35, ha="right", fontsize=7)
        ax.set_title(title, fontsize=8)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=6)


def _path_panel(ax, data: dict, names: list[str]) -> None:
    """The contact paths on the glenoid (decoupled), zoomed on them."""
    h, w = data["glenoid_height_mm"], data["glenoid_width_mm"]
    xs, ys = [], []
    for i, n in enumerate(names):
        path = data["shapes"][n]["runs"]["decoupled"].get("contact_path")
        if path:
            xs += [v for v in path["anterior_mm"] if np.isfinite(v)]
            ys += [v for v in path["superior_mm"] if np.isfinite(v)]
            ax.plot(path["anterior_mm"], path["superior_mm"], ".-", color=f"C{i % 10}", label=n)
            ax.plot(path["anterior_mm"][-1:], path["superior_mm"][-1:], "s", color=f"C{i % 10}")
    zoom = None
    if xs:  # the paths span a few mm of the 29 x 39 mm glenoid: show them, not the rim
        pad = 1.0
        zoom = ((min(xs) - pad, max(xs) + pad), (min(ys) - pad, max(ys) + pad))
    ax.set(xlabel="anterior (mm)", ylabel="superior (mm)", aspect="equal")
    if zoom is not None:
        ax.set(xlim=zoom[0], ylim=zoom[1])
    ax.set_title(
        f"contact path on the {w:g} x {h:g} mm glenoid (pressure-weighted centre), "
        "0 deg to the last angle (square)",
        fontsize=8,
    )
    ax.legend(fontsize=6, ncol=2)
    ax.grid(alpha=0.3)


def _glenoid_panel(ax, data: dict, names: list[str]) -> None:
    """The glenoid region's largest von Mises stress against the rotation, per shape."""
    for i, n in enumerate(names):
        r = data["shapes"][n]["runs"]["decoupled"]
        if "glenoid_von_mises_mpa" in r:
            x = r["contact_path"]["angles_deg"]
            ax.plot(x, r["glenoid_von_mises_mpa"][: len(x)], ".-", color=f"C{i % 10}", label=n)
    ax.set(xlabel="internal rotation (deg)", ylabel="MPa")
    ax.set_title(f"glenoid region ({GLENOID_REGION * 1e3:g} mm): largest von Mises", fontsize=9)
    ax.grid(alpha=0.3)


def _cost_panel(ax, data: dict, names: list[str]) -> None:
    """CPU time per shape: the decoupled run's stages, and the coupled run where it ran."""
    x = np.arange(len(names))
    bottom = np.zeros(len(names))
    for stage, colour in (("mesh", "0.7"), ("part1", "C0"), ("part2", "C2")):
        v = np.array(
            [data["shapes"][n]["runs"]["decoupled"]["stage_cpu_s"].get(stage) or 0.0 for n in names]
        )
        ax.bar(x - 0.2, v, 0.4, bottom=bottom, color=colour, label=f"decoupled: {stage}")
        bottom += v
    cpl = [data["shapes"][n]["runs"].get("coupled", {}).get("cpu_s", np.nan) for n in names]
    ax.bar(x + 0.2, cpl, 0.4, color="C3", label="coupled (total)")
    ax.set_xticks(x, names, rotation=35, ha="right", fontsize=7)
    ax.set_title("CPU time per shape (s)", fontsize=9)
    ax.legend(fontsize=6)
    ax.grid(alpha=0.3, axis="y")


def plot(data: dict, path: Path) -> None:
    """Nine panels: stresses, pressure and muscle forces against the shape at EARLY_ANGLE and at
    the last angle every shape reached; the contact paths, the glenoid stress, the cost."""
    names = list(data["shapes"])
    fig, axes = plt.subplots(3, 3, figsize=(15, 13), layout="constrained")
    _shape_panels(axes[0], data, names, EARLY_ANGLE)
    _shape_panels(axes[1], data, names, common_angle(data))
    _path_panel(axes[2, 0], data, names)
    _glenoid_panel(axes[2, 1], data, names)
    _cost_panel(axes[2, 2], data, names)
    fig.suptitle(
        f"{SCENE} ({data['level']}): head shape against the scapula's stress; decoupled for "
        "every shape (o), coupled on the checked ones (x)",
        fontsize=10,
    )
    save_figure(fig, path)


def main() -> None:
    matplotlib.use("Agg")
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--level", default="medium")
    ap.add_argument("--shapes", nargs="+", default=list(SHAPES), choices=list(SHAPES))
    ap.add_argument(
        "--check",
        nargs="+",
        default=["anatomical", "implant R22"],
        choices=list(SHAPES),
        help="shapes also run with the coupled method",
    )
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results"))
    ap.add_argument("--replot", action="store_true", help="redraw OUT/head_shape.png only")
    ap.add_argument(
        "--runs",
        type=Path,
        help="the run folders (default: TMPDIR/head-shape-runs-LEVEL); a finished run found "
        "there is read, not run again, so a study stopped part-way resumes",
    )
    args = ap.parse_args()
    if args.replot:
        plot(json.loads((args.out / "head_shape.json").read_text()), args.out / "head_shape.png")
        return
    g = geometry_from_values(load_scene(SCENE).values())
    data = {
        "scene": SCENE,
        "level": args.level,
        "final_angle_deg": round(math.degrees(load_scene(SCENE).values()["final_angle"]), 9),
        "glenoid_height_mm": g.glenoid_height * 1e3,
        "glenoid_width_mm": g.glenoid_width * 1e3,
        "glenoid_region_radius_mm": GLENOID_REGION * 1e3,
        "shapes": {},
    }
    reports = args.out / "head_shape_reports"
    runs_dir = args.runs or Path(tempfile.gettempdir()) / f"head-shape-runs-{args.level}"
    for name in args.shapes:
        overrides = shape_overrides(name)
        folders = {}
        runs = {}
        for method in ("decoupled", "coupled") if name in args.check else ("decoupled",):
            folders[method] = runs_dir / f"{slug(name)}-{method}"
            runs[method] = one(args.level, overrides, method, folders[method])
        entry = {"overrides": overrides, "runs": runs}
        if "coupled" in runs:
            target = reports / slug(name)
            shutil.rmtree(target, ignore_errors=True)
            entry["check"] = check(folders, args.level, target)
        data["shapes"][name] = entry
        print(
            name,
            {m: (r["status"], r["final_angle_deg"], r["cpu_s"]) for m, r in runs.items()},
            flush=True,
        )
    args.out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(args.out / "head_shape.json", data)
    plot(data, args.out / "head_shape.png")


if __name__ == "__main__":
    main()
