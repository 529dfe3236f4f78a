"""The scene commands: scenes, run, compare, bench, sweep, study.

Each takes the parsed arguments and returns the exit status; input errors are raised as
``SceneError`` / ``OutputError`` and a failed solve as :class:`SolverFailure` (``main`` turns
them into one line and an exit status).
"""

from __future__ import annotations

import sys
from pathlib import Path

#: Exit status of a command whose input cannot be used (:class:`InputFailure`, a SceneError...).
EXIT_INPUT = 2
#: Exit status of a command stopped by a solver failure (:class:`SolverFailure`).
EXIT_SOLVER = 3


class SolverFailure(RuntimeError):
    """A run stopped on a solver failure (exit status :data:`EXIT_SOLVER`)."""


class InputFailure(ValueError):
    """An input that cannot be used, e.g. a results folder to compare (:data:`EXIT_INPUT`)."""


def error(message: str) -> None:
    """Print ``shoulder-fem: error: <message>`` on rank 0's stderr."""
    from mpi4py import MPI

    if MPI.COMM_WORLD.rank == 0:
        print(f"shoulder-fem: error: {message}", file=sys.stderr)


def say(text: str) -> None:
    """Print ``text`` on rank 0's stdout."""
    from mpi4py import MPI

    if MPI.COMM_WORLD.rank == 0:
        print(text, flush=True)


def cmd_scenes(args) -> int:
    """List built-in scenes, one line each; with a name, that scene's parameters."""
    from shoulder_fem.scene import available_scenes, load_scene

    if getattr(args, "name", None):
        say(scene_parameters(load_scene(args.name)))
        return 0
    for name in available_scenes():
        scene = load_scene(name)
        say(f"{name:28s} {scene.summary}")
    return 0


def scene_parameters(scene) -> str:
    """A scene's parameters, one line each: name, value and bounds in the file's units, doc."""
    rows = [(name, *p.described(), p.doc) for name, p in scene.parameters.items()]
    w_name = max(len(r[0]) for r in rows)
    w_value = max(len(r[1]) for r in rows)
    w_bounds = max(len(r[2]) for r in rows)
    levels = ", ".join(scene.levels)
    lines = [
        f"{scene.name} ({scene.family}): {scene.summary}",
        f"source: {scene.source}; mesh levels: {levels} (default {scene.default_level})",
        "set with --set KEY=VALUE (SI, or a value with a unit of the right kind)",
        "",
        f"{'parameter':{w_name}s}  {'value':{w_value}s}  {'bounds':{w_bounds}s}  doc",
    ]
    for name, value, bounds, doc in rows:
        lines.append(f"{name:{w_name}s}  {value:{w_value}s}  {bounds:{w_bounds}s}  {doc}")
    return "\n".join(lines)


def prepare(args):
    """The scene with ``--set`` applied (checked) and the linear solver's options."""
    from shoulder_fem.api import check_method
    from shoulder_fem.engine.solver import linear_solver_options
    from shoulder_fem.scene import load_scene

    scene = load_scene(args.scene).with_overrides(args.sets)
    if getattr(args, "method", None):
        check_method(args.method)
    scene.level(args.level)
    from shoulder_fem.cli.args import petsc_options

    petsc_options(getattr(args, "petsc", []))  # a malformed --petsc: an input error now
    return scene, linear_solver_options(args.linear_solver)


def cmd_run(args) -> int:
    """Run one scene with one method."""
    from shoulder_fem.api import RunFailed, run
    from shoulder_fem.cli.args import petsc_options

    scene, options = prepare(args)
    try:
        result = run(
            scene,
            args.method,
            args.level,
            args.out,
            solver_options=options,
            make_parents=False,
            petsc_options=petsc_options(args.petsc),
            replace=args.force,
        )
    except RunFailed as err:
        raise SolverFailure(str(err)) from err
    say(_probe_lines(result.data))
    say(f"results: {result.folder}")
    raise_unless_finished(result.data, "run", result.folder)
    return 0


def raise_unless_finished(summary: dict, command: str, folder) -> None:
    """Raise :class:`SolverFailure` (exit status 3) unless ``summary`` is a finished run's.

    A run that stopped short of its final angle keeps its completed steps with the status
    ``incomplete`` and a message naming the angle reached and the reason: its command ends
    with that line and exit status 3, as a failed solve does.
    """
    status = summary.get("status")
    if status != "ok":
        raise SolverFailure(
            f"{command}: {summary.get('message')} (status '{status}'; the steps before it are "
            f"in {folder})"
        )


def cmd_sweep(args) -> int:
    """Part 2 for every combination of the swept values, from one decoupled run's part 1."""
    from mpi4py import MPI

    from shoulder_fem.api import RunFailed, sweep
    from shoulder_fem.scene import load_scene

    scene = load_scene(args.scene)
    try:
        data = sweep(scene, args.source, args.sets, args.out, MPI.COMM_WORLD)
    except RunFailed as err:
        raise SolverFailure(str(err)) from err
    for row in data["variants"]:
        values = ", ".join(f"{k}={v}" for k, v in row["values"].items())
        peak = max(row["von_mises_max_mpa"], default=float("nan"))
        say(
            f"{values}: {row['status']}, part 2 CPU {row['part2_cpu_s']:.2f} s "
            f"(run {row['cpu_s']:.2f} s), largest von Mises {peak:.3f} MPa"
        )
    say(f"sweep: {args.out}/sweep.json, sweep.png")
    short = [r for r in data["variants"] if r["status"] != "ok"]
    if short:
        names = ", ".join(r["folder"] for r in short)
        raise SolverFailure(f"sweep: {len(short)} variant(s) did not finish: {names}")
    return 0


def cmd_study(args) -> int:
    """One whole run per combination of the studied values; exit 3 if one did not finish."""
    from mpi4py import MPI

    from shoulder_fem.api import study
    from shoulder_fem.scene import load_scene

    scene = load_scene(args.scene)
    data = study(scene, args.sets, args.out, args.method, args.level, MPI.COMM_WORLD)
    for row in data["variants"]:
        values = ", ".join(f"{k}={v}" for k, v in row["values"].items())
        line = f"{values}: {row['status']}, CPU {row['cpu_s']:.1f} s, wall {row['wall_s']:.1f} s"
        say(line + (f" ({row['message']})" if row["status"] != "ok" else ""))
    say(f"study: {args.out}/study.json, study.png, study.pdf")
    if not data["finished"]:
        short = [r for r in data["variants"] if r["status"] != "ok"]
        listed = "; ".join(f"{r['folder']}: {r['message']}" for r in short)
        raise SolverFailure(
            f"study: {len(short)} of {len(data['variants'])} variant(s) did not reach the "
            f"final angle: {listed}"
        )
    return 0


def _probe_lines(summary: dict) -> str:
    res = summary["resources"]
    lines = [
        f"{summary['scene']} / {summary['method']} / {summary['level']}: "
        f"CPU {res['cpu_s']:.2f} s, wall {res['wall_s']:.2f} s, "
        f"peak memory {res['peak_rss_mb']:.0f} MB, {summary.get('dofs')} DOFs, "
        f"{res['ranks']} rank(s)"
    ]
    units = summary.get("probe_units", {})
    width = max((len(name) for name in summary["probes"]), default=0)
    for name, value in summary["probes"].items():
        unit = units.get(name) or ""
        unit = "–" if unit == "1" else unit  # dimensionless
        text = f"{value:.6g}" if isinstance(value, float) else str(value)
        lines.append(f"  {name:{width}s}  {text} {unit}".rstrip())
    return "\n".join(lines)


def cmd_compare(args) -> int:
    """Compare two finished runs; write comparison.json and figures."""
    from mpi4py import MPI

    from shoulder_fem.io.output import OutputDir

    comm = MPI.COMM_WORLD
    ref, other = _compared_run(args.ref, "reference"), _compared_run(args.other, "other")
    if ref["scene"] != other["scene"]:
        raise InputFailure(
            f"compare: runs of different scenes: {args.ref} is '{ref['scene']}', "
            f"{args.other} is '{other['scene']}'"
        )
    with OutputDir(args.out, comm, replace=args.force) as out:
        report = write_comparison(ref, other, out.path, comm)
    say(_comparison_lines(report))
    say(f"comparison: {args.out}")
    for folder, summary in ((args.ref, ref), (args.other, other)):
        if summary.get("status") != "ok":  # compared all the same, and said
            raise SolverFailure(
                f"compare: {folder} is a run with status '{summary.get('status')}' "
                f"({summary.get('message')}); the comparison covers what it reached"
            )
    return 0


#: What a run's summary.json must hold to be compared.
_SUMMARY_KEYS = ("scene", "method", "status", "series", "probes", "resources")


def _compared_run(folder: Path, role: str) -> dict:
    """The summary of a run folder to compare.

    Raises:
        InputFailure: No such folder, no ``summary.json`` in it, or one that is not a run's
            summary (not JSON, keys missing).
    """
    import json

    from shoulder_fem.io.results import load_summary

    try:
        summary = load_summary(folder)
    except FileNotFoundError as err:
        raise InputFailure(f"compare: {role} run: {err}") from err
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise InputFailure(f"compare: {folder}/summary.json is not valid JSON ({err})") from err
    missing = [k for k in _SUMMARY_KEYS if not isinstance(summary, dict) or k not in summary]
    if missing:
        raise InputFailure(
            f"compare: {folder}/summary.json is not a run's summary (missing: {', '.join(missing)})"
        )
    return summary


def write_comparison(ref: dict, other: dict, folder: Path, comm) -> dict:
    """Metrics + figures of ``other`` against ``ref`` into ``folder`` (rank 0 writes)."""
    from shoulder_fem.io.compare import compare_summaries
    from shoulder_fem.io.output import atomic_write_json

    report = compare_summaries(ref, other)
    if comm.rank == 0:
        from shoulder_fem.io import plots

        atomic_write_json(folder / "comparison.json", report)
        for name in report["series"]:
            if name.endswith("_analytic"):
                continue
            analytic = ref["series"].get(f"{name}_analytic")
            reference = None
            if analytic is not None:
                reference = (analytic["x"], analytic["y"], "analytic")
            plots.plot_series([ref, other], name, folder / f"{name}.png", reference=reference)
        plots.plot_resources({ref["method"]: ref, other["method"]: other}, folder / "resources.png")
    return report


def _comparison_lines(report: dict) -> str:
    lines = [
        f"{report['scene']}: {report['other']['method']} against {report['reference']['method']}"
    ]
    for role in ("reference", "other"):
        info = report[role]
        if info.get("validity") == "outside":
            lines.append(
                f"  OUTSIDE VALIDITY ({role}, {info['method']}): {info.get('validity_reason')}"
            )
    for name, p in report["probes"].items():
        lines.append(
            f"  {name:28s} ref {p['reference']:.6g}  other {p['other']:.6g}  "
            f"rel. diff {p['relative_difference']:+.2e}"
        )
    for name, s in report["series"].items():
        lines.append(
            f"  series {name:21s} max rel. diff {s['max_rel_diff']:.2e}  "
            f"correlation {s['correlation']:.6f}  slope {s['slope']:.4f}"
        )
    r = report["resources"]
    lines.append(f"  speed-up (CPU) {r['speedup_cpu']:.2f}x   memory ratio {r['memory_ratio']:.2f}")
    return "\n".join(lines)


def generic_report(bench) -> str:
    """The ``bench`` report of a family without its own: metrics, figures, resources table."""
    from shoulder_fem.io.compare import resources_table
    from shoulder_fem.io.output import atomic_write_json, atomic_write_text

    coupled, decoupled = bench.runs["coupled"], bench.runs["decoupled"]
    report = write_comparison(coupled, decoupled, bench.folder, bench.comm)
    report["speedup_cpu"] = report["resources"]["speedup_cpu"]
    report["memory_ratio"] = report["resources"]["memory_ratio"]
    table = resources_table(bench.runs)
    if bench.comm.rank == 0:
        atomic_write_json(bench.folder / "report.json", report)
        md = [
            f"# {bench.scene.name}: coupled against decoupled ({bench.level})",
            "",
            "## Resources",
            "",
            table,
            "",
            "## Results",
            "",
            "```",
            _comparison_lines(report),
            "```",
            "",
        ]
        atomic_write_text(bench.folder / "report.md", "\n".join(md))
    lines = [_probe_lines(coupled), _probe_lines(decoupled), _comparison_lines(report), table]
    return "\n".join(lines)
