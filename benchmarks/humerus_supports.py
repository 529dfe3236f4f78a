"""Benchmark: how the humerus swings on its supports, and where that puts the joint's contact.

    OMP_NUM_THREADS=1 python benchmarks/humerus_supports.py --levels coarse --jobs 2 \
        --out benchmarks/results

Issue 20, items 4 and 5. The paper holds the distal humerus with "four vertical flexible
elements, precluding any significant movement in abduction". The scene's humerus is abducted
about 50 deg (its shaft 50 deg from the vertical), so vertical elements resist a change of its
elevation; nothing of the paper's resists a horizontal swing (a turn of the shaft about the
vertical). The decoupled method (the coupled one records the same swing within 0.1 deg at
coarse, ``test_shoulder``) turns the humerus 0-60 deg on both humeral cartilage caps with:

* ``paper``: the scene's elements, 100 mm axial links from the distal patches to their ground
  points (``spring_length``; the default);
* ``fixed-direction``: the same elements 10 m long, so that they act along the vertical
  whatever the distal section's horizontal travel (a fixed-direction spring, as a spring to
  ground acting on one degree of freedom);
* ``horizontal <k>``: the paper's elements and the two horizontal ones (lateral, anterior, on
  the shaft axis; ``humerus_horizontal_stiffness``, our addition, an option) of stiffness k.

Per run and output angle: the swing split into the change of the shaft's elevation and of its
azimuth about the vertical (``humeral_swing_elevation``, ``humeral_swing_azimuth``), where the
glenoid presses on the humeral cartilage and the margin to its edge, the supports' forces, the
peak glenoid pressure and the muscle forces; per run its status, steps, Newton iterations and
CPU time and the commit it was measured on. Writes ``humerus_supports.json`` (an existing one
is updated: the cases run now replace theirs) and ``humerus_supports.png``. Every figure is
measured; it asserts nothing.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import matplotlib
import numpy as np
from model_changes import one, source_commit  # a sibling script: benchmarks/ is sys.path[0]

from shoulder_fem.io.output import atomic_write_json
from shoulder_fem.io.plots import plt, save_figure
from shoulder_fem.meshes.shoulder import ANATOMICAL_CAP

CAPS = {"70": [], "78": list(ANATOMICAL_CAP)}
SUPPORTS = {
    "paper": [],
    "fixed-direction": ["spring_length=10000mm"],
    "horizontal 1 N/mm": ["humerus_horizontal_stiffness=1N/mm"],
    "horizontal 5 N/mm": ["humerus_horizontal_stiffness=5N/mm"],
}
SERIES = (
    "humeral_swing",
    "humeral_swing_elevation",
    "humeral_swing_azimuth",
    "humeral_cap_contact_angle",
    "humeral_cap_contact_angle_max",
    "humeral_cap_edge_margin",
    "humerus_distal_support_force",
    "humerus_horizontal_support_force",
    "max_pressure",
    "subscapularis_force",
    "infraspinatus_force",
    "supraspinatus_force",
)
PANELS = (
    ("humeral_swing_azimuth", 1.0, "deg", "horizontal swing (azimuth)"),
    ("humeral_swing_elevation", 1.0, "deg", "change of elevation (+ = abduction)"),
    ("humeral_cap_contact_angle_max", 1.0, "deg", "farthest contact point on the cap"),
    ("humerus_distal_support_force", 1.0, "N", "vertical elements, sum of |tension|"),
    ("humerus_horizontal_support_force", 1.0, "N", "horizontal elements, sum of |tension|"),
    ("subscapularis_force", 1.0, "N", "subscapularis force"),
)


def _case(job: tuple) -> tuple[str, str, str, dict]:
    level, support, cap, extra, tmp = job
    out = Path(tmp) / f"{level}-{support.replace(' ', '_').replace('/', '')}-{cap}"
    r = one(level, SUPPORTS[support] + CAPS[cap] + extra, "decoupled", out, series=SERIES)
    return level, support, cap, {"support": support, "cap": cap, "extra": extra, **r}


def case_name(support: str, cap: str, extra: list[str]) -> str:
    """The JSON key of a case: ``<support>, <cap> deg cap`` and any ``--set`` in brackets."""
    return f"{support}, {cap} deg cap" + (f" [{' '.join(extra)}]" if extra else "")


def plot(data: dict, path: Path) -> None:
    """The swing's parts, the contact's reach, the supports' forces against the twist."""
    fig = plt.figure(figsize=(15, 11), layout="constrained")
    grid = fig.add_gridspec(3, 3, height_ratios=(1.0, 1.0, 0.5))
    axes = np.array([fig.add_subplot(grid[i, j]) for i in range(2) for j in range(3)])
    legend_ax = fig.add_subplot(grid[2, :])
    legend_ax.axis("off")
    colours = {s: f"C{k}" for k, s in enumerate(SUPPORTS)}
    styles = {"70": ":", "78": "-"}
    widths = {"medium": 2.4, "paper": 3.4}
    for level, cases in data["levels"].items():
        for name, r in cases.items():
            cap = r["cap"]
            kw = {"color": colours[r["support"]], "ls": styles[cap], "lw": widths.get(level, 1.2)}
            kw["marker"] = "x" if r["extra"] else "."
            label = f"{name}, {level} (to {r['final_angle_deg']:.1f} deg)"
            for ax, (key, scale, _, _) in zip(axes.flat, PANELS, strict=True):
                if key in r["series"]:
                    s = r["series"][key]
                    ax.plot(s["x"], [v * scale for v in s["y"]], **kw, label=label)
            # each cap's edge as the run measured it on its mesh (70.14 deg for the 70 cap)
            axes.flat[2].axhline(r["cap_half_angle_deg"], color="0.5", lw=0.6, ls=styles[cap])
    for ax, (_, _, unit, title) in zip(axes.flat, PANELS, strict=True):
        ax.set(xlabel="internal rotation (deg)", ylabel=unit, title=title)
    legend_ax.legend(*axes[0].get_legend_handles_labels(), loc="center", ncol=2, fontsize=8)
    fig.suptitle(
        "decoupled method: the humerus on the paper's vertical elements (100 mm links or fixed "
        "direction) and with horizontal elements\ncaps 70 deg (dotted) and 78 deg (solid); grey "
        "lines: the caps' edges; thicker lines: finer levels; crosses: with --set overrides"
    )
    save_figure(fig, path)


def main() -> None:
    matplotlib.use("Agg")
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--levels", nargs="+", default=["coarse"])
    ap.add_argument("--supports", nargs="+", default=list(SUPPORTS), choices=list(SUPPORTS))
    ap.add_argument("--caps", nargs="+", default=list(CAPS), choices=list(CAPS))
    ap.add_argument("--jobs", type=int, default=1, help="runs at a time, one core each")
    ap.add_argument("--set", nargs="*", default=[], help="more overrides, for every case")
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results"))
    args = ap.parse_args()
    path = args.out / "humerus_supports.json"
    data = json.loads(path.read_text()) if path.is_file() else {"levels": {}}  # updated
    data.update(scene="shoulder-internal-rotation", method="decoupled", supports=SUPPORTS)
    data["caps"] = CAPS
    commit = source_commit()
    with tempfile.TemporaryDirectory(prefix="humerus-supports-") as tmp:
        jobs = [
            (lv, s, c, args.set, tmp)
            for lv in args.levels
            for s in args.supports
            for c in args.caps
        ]
        ctx = multiprocessing.get_context("spawn")  # each run its own MPI and PETSc
        with ProcessPoolExecutor(max_workers=args.jobs, mp_context=ctx) as pool:
            for level, support, cap, r in pool.map(_case, jobs):
                r["measured"] = commit
                data["levels"].setdefault(level, {})[case_name(support, cap, args.set)] = r
                print(level, support, cap, r["status"], f"{r['final_angle_deg']:.2f} deg")
    args.out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(path, data)
    plot(data, args.out / "humerus_supports.png")


if __name__ == "__main__":
    main()
