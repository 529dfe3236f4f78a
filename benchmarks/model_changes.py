"""Benchmark: how far each earlier simplification of the shoulder model moved its results.

    OMP_NUM_THREADS=1 python benchmarks/model_changes.py --levels coarse medium \
        --out benchmarks/results

Both methods, 0-60 deg, on the scene and on variants that put back one earlier simplification
at a time (issue 20, item 9):

* ``whole``: the scene as it is (the paper's 4 vertical distal elements, the rotator cuff
  sliding on the humeral head and the scapula, the incompressible cartilage and muscles, the
  glenohumeral penalty 200 MPa/mm on the curved articular surfaces);
* ``compressible-muscles``: the earlier muscles, nu = 0.49, and the cartilages without the
  pointwise stabilisation (the default before 2026-11-29);
* ``compressible``: the earlier cartilage, nu = 0.4, and muscles, at 100 MPa/mm (the default
  before the incompressible cartilage);
* ``flat``: the articular surfaces as the mesh's flat facets at 60 MPa/mm, the compressible
  cartilage (the default before the curved surfaces: the facets' misfit set the penalty's
  overlap);
* ``penalty``: the earlier glenohumeral penalty, 5 MPa/mm on the flat facets (about half of
  the joint's normal compliance its own);
* ``head-only``: the cuff slides on the humeral head only (through the scapula);
* ``no-cuff-contact``: no muscle-bone contact (the muscles pass through bone);
* ``supports``: two horizontal distal elements of 5 N/mm added (they hold the humerus's swing);
* ``earlier``: the defaults before 2026-11-27, all of the above at once.

Per run and output angle: the peak glenoid pressure, the muscle forces, the scapula's largest
nodal von Mises stress, the humerus's swing, the contact's reach on the humeral cartilage, the
supports' forces and the cuff's force on the head; per run its status, steps, failed steps,
Newton iterations and CPU time. Writes ``model_changes.json`` and ``model_changes.png`` (the
coupled runs; the decoupled ones are in the JSON). Every figure is measured; it asserts nothing.

An existing ``model_changes.json`` in ``--out`` is updated, not replaced: the levels and
variants run now replace their entries, the others keep theirs. It is written after every
variant, so an interrupted sweep keeps the variants it finished. Each entry names the commit
and the date it was measured on (``measured``), so a partial rerun (``--levels coarse``) says
which entries are older.
"""

from __future__ import annotations

import argparse
import datetime
import json
import subprocess
import tempfile
from pathlib import Path

import matplotlib

from shoulder_fem import load_scene, run
from shoulder_fem.io.output import atomic_write_json
from shoulder_fem.io.plots import plt, save_figure

FLAT = "contact_surfaces=flat"
COMPRESSIBLE = "soft_tissue_formulation=compressible"
EARLIER_PENALTY = "contact_penalty=5MPa/mm"
EARLIER_SUPPORTS = "humerus_horizontal_stiffness=5N/mm"
VARIANTS = {
    "whole": [],
    "compressible-muscles": [
        "soft_tissue_formulation=incompressible-cartilage",
        "soft_tissue_pointwise_bulk_ratio=0",
    ],
    "compressible": [COMPRESSIBLE, "contact_penalty=100MPa/mm"],
    "flat": [COMPRESSIBLE, FLAT, "contact_penalty=60MPa/mm"],
    "penalty": [FLAT, EARLIER_PENALTY],
    "head-only": ["muscle_contact=humeral-head"],
    "no-cuff-contact": ["muscle_contact=none"],
    "supports": [EARLIER_SUPPORTS],
    "earlier": [EARLIER_SUPPORTS, "muscle_contact=none", COMPRESSIBLE, FLAT, EARLIER_PENALTY],
}
SERIES = (
    "max_pressure",
    "subscapularis_force",
    "infraspinatus_force",
    "supraspinatus_force",
    "scapula_max_von_mises",
    "humeral_swing",
    "humeral_cap_contact_angle_max",
    "humerus_distal_support_force",
    "humerus_horizontal_support_force",
    "muscle_bone_contact_force",
    "glenohumeral_penetration",
    "glenohumeral_penalty_share",
)
METHODS = ("coupled", "decoupled")


def record(r, series: tuple[str, ...]) -> dict:
    """A finished run's status, counters, CPU time and ``series`` (also ``muscle_mesh.py``'s)."""
    p = r.probes
    return {
        "status": r.status,
        "final_angle_deg": p["final_angle_deg"],
        "steps": p["steps"],
        "failed_steps": p["failed_steps"],
        "newton_iterations": p["newton_iterations"],
        "cpu_s": r.resources["cpu_s"],
        "series": {
            k: {"x": r.series[k]["x"], "y": r.series[k]["y"]} for k in series if k in r.series
        },
    }


def one(
    level: str, overrides: list[str], method: str, out: Path, series: tuple[str, ...] = SERIES
) -> dict:
    """One run's status, counters and ``series`` (also ``cartilage_cap.py``'s runs)."""
    scene = load_scene("shoulder-internal-rotation").with_overrides(overrides)
    r = run(scene, method, level=level, out=out)
    cap = r.probes["humeral_cap_half_angle_deg"]
    return {"overrides": overrides, "cap_half_angle_deg": cap, **record(r, series)}


PANELS = (
    ("max_pressure", 1e-6, "MPa", "peak glenoid pressure"),
    ("subscapularis_force", 1.0, "N", "subscapularis force"),
    ("infraspinatus_force", 1.0, "N", "infraspinatus force"),
    ("scapula_max_von_mises", 1e-6, "MPa", "scapula's largest nodal von Mises"),
    ("humeral_swing", 1.0, "deg", "humerus swing"),
    ("humeral_cap_contact_angle_max", 1.0, "deg", "contact's reach on the humeral cap"),
)


def plot(data: dict, path: Path) -> None:
    """The coupled runs' series, one panel per quantity, one line per variant and level."""
    fig, axes = plt.subplots(2, 3, figsize=(14, 7.5), layout="constrained")
    palette = ("C0", "C8", "C7", "C6", "C1", "C4", "C5", "C2", "C3")
    colours = dict(zip(VARIANTS, palette, strict=True))
    styles = {"coarse": ":", "medium": "-", "paper": "--"}
    for level, cases in data["levels"].items():
        for case, runs in cases.items():
            s = runs["coupled"]["series"]
            commit = runs["coupled"].get("measured", {}).get("commit", "?")
            for ax, (key, scale, unit, title) in zip(axes.flat, PANELS, strict=True):
                if key in s:
                    kw = {"color": colours[case], "ls": styles.get(level, "-")}
                    ax.plot(
                        s[key]["x"],
                        [v * scale for v in s[key]["y"]],
                        **kw,
                        label=f"{case}, {level} ({commit})",
                    )
                ax.set(xlabel="internal rotation (deg)", ylabel=unit, title=title)
        edge = next(iter(cases.values()))["coupled"]["cap_half_angle_deg"]
    axes.flat[5].axhline(edge, color="k", lw=0.8)
    axes.flat[5].text(2, edge + 1, "edge of the humeral cartilage", fontsize=7)
    axes.flat[0].legend(fontsize=7)
    fig.suptitle(
        "coupled method; whole = the scene (paper's supports, cuff on the bones, incompressible "
        "cartilage and muscles, curved surfaces, 200 MPa/mm) at the commit in brackets "
        "(before 134d253 the muscles had nu = 0.49);\n"
        "each other line puts back one earlier simplification, earlier = all of them",
        fontsize=9,
    )
    save_figure(fig, path)


def source_commit() -> str:
    """The commit of the checkout this script runs from (``+dirty`` if it has changes)."""
    here = Path(__file__).resolve().parent

    def git(*cmd: str) -> str:
        done = subprocess.run(["git", *cmd], cwd=here, capture_output=True, text=True)
        return done.stdout.strip() if done.returncode == 0 else ""

    commit = git("rev-parse", "--short", "HEAD") or "unknown"
    return commit + ("+dirty" if git("status", "--porcelain", "--untracked-files=no") else "")


def earlier(path: Path) -> dict:
    """The results already in ``path`` (the variants' definitions renewed), or none."""
    data = {"scene": "shoulder-internal-rotation", "levels": {}}
    if path.is_file():
        data = json.loads(path.read_text())
    data["variants"] = VARIANTS
    return data


def main() -> None:
    matplotlib.use("Agg")
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--levels", nargs="+", default=["coarse", "medium"])
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results"))
    ap.add_argument(
        "--plot-only", action="store_true", help="redraw the figure from the JSON; run nothing"
    )
    args = ap.parse_args()
    data = earlier(args.out / "model_changes.json")
    if args.plot_only:
        plot(data, args.out / "model_changes.png")
        return
    measured = {"commit": source_commit(), "date": datetime.date.today().isoformat()}
    args.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="model-changes-") as tmp:
        for level in args.levels:
            for case in args.variants:
                runs = {
                    m: {
                        **one(level, VARIANTS[case], m, Path(tmp) / f"{level}-{case}-{m}"),
                        "measured": measured,
                    }
                    for m in METHODS
                }
                print(level, case, {m: runs[m]["status"] for m in METHODS}, flush=True)
                # written after every variant: an interrupted sweep keeps what it finished
                data["levels"].setdefault(level, {})[case] = runs
                atomic_write_json(args.out / "model_changes.json", data)
    plot(data, args.out / "model_changes.png")


if __name__ == "__main__":
    main()
