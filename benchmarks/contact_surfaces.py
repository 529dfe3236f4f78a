"""Benchmark: the glenohumeral contact on flat facets and on curved surfaces (issue 20, item 3).

    OMP_NUM_THREADS=1 python benchmarks/contact_surfaces.py --level medium --out benchmarks/results

The mesh's straight-sided tetrahedra make the articular spheres flat facets whose middles lie
h^2/(8R) inside them, of the order of the cartilages' compression. This runs the shoulder scene
at one level, 0-60 deg, with the decoupled method (part 1 holds the joint; ``--methods`` for
others), for every pair of ``--surfaces`` (``contact_surfaces``: flat, curved) and
``--penalties`` (``contact_penalty``, MPa/mm). Per run and output angle: the penalty's share of
the joint's compliance by stored energy and by the nodal measure, the contact points' area,
the deepest overlap, the peak (nodal) pressure and the three muscle forces; per run its status,
steps, failed steps, Newton iterations and CPU time. Writes ``contact_surfaces_<level>.json``
and ``.png``. Every figure is measured; it asserts nothing.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import matplotlib
from model_changes import one  # a sibling script: benchmarks/ is sys.path[0]

from shoulder_fem.io.output import atomic_write_json
from shoulder_fem.io.plots import plt, save_figure

SERIES = (
    "glenohumeral_penalty_energy_share",
    "glenohumeral_penalty_share",
    "contact_area",
    "glenohumeral_penetration",
    "max_pressure",
    "subscapularis_force",
    "infraspinatus_force",
    "supraspinatus_force",
)
PANELS = (
    ("glenohumeral_penalty_energy_share", 1e2, "%", "penalty's share by stored energy"),
    ("glenohumeral_penalty_share", 1e2, "%", "penalty's share, nodal measure"),
    ("contact_area", 1e6, "mm^2", "contact points' area"),
    ("glenohumeral_penetration", 1e6, "um", "deepest overlap"),
    ("max_pressure", 1e-6, "MPa", "peak (nodal) glenoid pressure"),
    ("subscapularis_force", 1.0, "N", "subscapularis force"),
)


def plot(data: dict, path: Path) -> None:
    """One panel per quantity against the angle, one line per surface and penalty."""
    fig, axes = plt.subplots(2, 3, figsize=(14, 7.5), layout="constrained")
    for r in data["runs"]:
        colour = "tab:blue" if r["surfaces"] == "flat" else "tab:red"
        ls = "--" if r["penalty_mpa_mm"] < max(x["penalty_mpa_mm"] for x in data["runs"]) else "-"
        label = f"{r['surfaces']}, {r['penalty_mpa_mm']:g} MPa/mm, {r['method']}"
        for ax, (key, scale, unit, title) in zip(axes.flat, PANELS, strict=True):
            s = r["series"].get(key)
            if s:
                y = [v * scale for v in s["y"]]
                ax.plot(s["x"], y, color=colour, ls=ls, marker="o", ms=3, label=label)
            ax.set(xlabel="internal rotation (deg)", ylabel=unit, title=title)
    axes.flat[0].axhline(10.0, color="grey", lw=0.8, ls=":", label="issue 20's bound, 10 %")
    axes.flat[0].legend(fontsize=7)
    fig.suptitle(
        f"level {data['level']}: the glenohumeral contact's surfaces and penalty", fontsize=9
    )
    save_figure(fig, path)


def main() -> None:
    matplotlib.use("Agg")
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--level", default="medium")
    ap.add_argument("--surfaces", nargs="+", default=["flat", "curved"])
    ap.add_argument("--penalties", nargs="+", type=float, default=[60.0, 100.0])
    ap.add_argument("--methods", nargs="+", default=["decoupled"])
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results"))
    args = ap.parse_args()
    data = {"scene": "shoulder-internal-rotation", "level": args.level, "runs": []}
    with tempfile.TemporaryDirectory(prefix="contact-surfaces-") as tmp:
        for surfaces in args.surfaces:
            for eps in args.penalties:
                for m in args.methods:
                    sets = [f"contact_surfaces={surfaces}", f"contact_penalty={eps:g}MPa/mm"]
                    r = one(args.level, sets, m, Path(tmp) / f"{surfaces}-{eps:g}-{m}", SERIES)
                    r.update(surfaces=surfaces, penalty_mpa_mm=eps, method=m)
                    data["runs"].append(r)
                    print(
                        f"{surfaces} {eps:g} MPa/mm {m}: {r['status']} "
                        f"{r['final_angle_deg']:.2f} deg, {r['steps']} steps "
                        f"({r['failed_steps']} failed), {r['newton_iterations']} Newton, "
                        f"{r['cpu_s']:.0f} s",
                        flush=True,
                    )
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / f"contact_surfaces_{args.level}.json"
    atomic_write_json(path, data)
    plot(data, path.with_suffix(".png"))


if __name__ == "__main__":
    main()
