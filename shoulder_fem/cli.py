"""The ``shoulder-fem`` command: scenes, run, compare, bench.

``main(argv) -> int``; heavy imports (dolfinx, PETSc) happen inside the commands so that
``--help`` is instant. Under ``mpirun -n N`` every command behaves the same and writes its
output once. Errors in the input print one line naming what is wrong and exit with status 2;
a diverged solve exits with status 3 after writing the completed steps. SIGTERM (``kill``, a
batch system's time limit) unwinds the run like an error: the unfinished output folder is
removed, and the command exits with status 143.
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
from pathlib import Path

from .scene import LEVELS

logger = logging.getLogger("shoulder_fem")

EXIT_INPUT = 2
EXIT_SOLVER = 3
EXIT_TERMINATED = 128 + signal.SIGTERM  # 143, the shell's status for a process ended by SIGTERM


class _Terminated(SystemExit):
    """Raised by the SIGTERM handler.

    Not an ``Exception``: no ``except Exception`` stops it on its way out, and every ``with``
    block (the output folders) unwinds.
    """


def _raise_on_sigterm(signum, frame) -> None:
    raise _Terminated(EXIT_TERMINATED)


class _RankFilter(logging.Filter):
    def __init__(self, rank: int, all_ranks: bool):
        super().__init__()
        self.rank, self.all_ranks = rank, all_ranks

    def filter(self, record: logging.LogRecord) -> bool:
        record.rank_prefix = f"CPU {self.rank}: " if self.all_ranks else ""
        return self.all_ranks or self.rank == 0


def setup_logging(verbosity: int, all_ranks: bool) -> None:
    """Configure the package logger once: rank 0 only unless ``all_ranks``."""
    from mpi4py import MPI

    # Claim the root logger first, so a library's later logging.basicConfig (the form compiler's
    # build steps log at INFO through it) is a no-op and stays quiet below -vv.
    logging.basicConfig(level=logging.DEBUG if verbosity > 1 else logging.WARNING)
    handler = logging.StreamHandler(sys.stderr)
    handler.addFilter(_RankFilter(MPI.COMM_WORLD.rank, all_ranks))
    handler.setFormatter(logging.Formatter("%(asctime)s %(rank_prefix)s%(message)s", "%H:%M:%S"))
    logger.handlers[:] = [handler]
    logger.setLevel({0: logging.WARNING, 1: logging.INFO}.get(verbosity, logging.DEBUG))
    logger.propagate = False


def build_parser() -> argparse.ArgumentParser:
    """The argument parser (one sub-command each)."""
    parser = argparse.ArgumentParser(
        prog="shoulder-fem",
        description="Large motions with small strains: coupled and decoupled FEniCSx solvers.",
    )
    parser.add_argument(
        "-v", "--verbose", action="count", default=1, help="more log lines (-vv: debug)"
    )
    parser.add_argument("-q", "--quiet", action="store_true", help="warnings and errors only")
    parser.add_argument(
        "--log-all-ranks", action="store_true", help="log from every MPI rank, prefixed 'CPU n:'"
    )
    sub = parser.add_subparsers(dest="command", required=True)

    sub.add_parser("scenes", help="list the built-in scenes")

    p = sub.add_parser("run", help="run one scene with one method")
    p.add_argument("scene", help="built-in scene name or path to a .toml scene file")
    p.add_argument("--method", required=True, choices=["coupled", "decoupled"])
    _common_run_args(p)

    p = sub.add_parser("compare", help="compare two runs (reference first)")
    p.add_argument("ref", type=Path, help="output folder of the reference run (coupled)")
    p.add_argument("other", type=Path, help="output folder of the other run (decoupled)")
    p.add_argument("--out", type=Path, required=True, help="folder for metrics and figures")

    p = sub.add_parser("bench", help="run both methods and write the comparison report")
    p.add_argument("scene", help="built-in scene name or path to a .toml scene file")
    _common_run_args(p)

    from .mesh_command import add_mesh_parser

    add_mesh_parser(sub)
    return parser


def add_scene_arguments(p: argparse.ArgumentParser, example: str = "spin_rate=600rpm") -> None:
    """``--level`` and ``--set KEY=VALUE`` (repeatable), shared by every scene command."""
    p.add_argument(
        "--level",
        choices=list(LEVELS),
        default=None,
        help="mesh level (default: the scene's)",
    )
    p.add_argument(
        "--set",
        dest="sets",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help=f"override a scene parameter (SI, or with a unit: {example})",
    )


def _common_run_args(p: argparse.ArgumentParser) -> None:
    add_scene_arguments(p)
    p.add_argument("--out", type=Path, required=True, help="output folder (written atomically)")
    p.add_argument(
        "--linear-solver",
        choices=["direct", "iterative"],
        default="direct",
        help="MUMPS LU (default) or CG + GAMG with rigid-body near-nullspace",
    )


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit status."""
    args = build_parser().parse_args(argv)
    verbosity = 0 if args.quiet else args.verbose
    setup_logging(verbosity, args.log_all_ranks)
    from .results import OutputError
    from .scene import SceneError

    signal.signal(signal.SIGTERM, _raise_on_sigterm)
    try:
        return {
            "scenes": cmd_scenes,
            "run": cmd_run,
            "compare": cmd_compare,
            "bench": cmd_bench,
            "mesh": _cmd_mesh,
        }[args.command](args)
    except (SceneError, OutputError) as err:
        _error(str(err))
        return EXIT_INPUT
    except _SolverFailure as err:
        _error(str(err))
        return EXIT_SOLVER
    except _Terminated:
        out = getattr(args, "out", None)
        where = f": the unfinished output {out} was removed" if out else ""
        _error(f"stopped by SIGTERM{where}")
        return EXIT_TERMINATED


class _SolverFailure(RuntimeError):
    pass


def _error(message: str) -> None:
    from mpi4py import MPI

    if MPI.COMM_WORLD.rank == 0:
        print(f"shoulder-fem: error: {message}", file=sys.stderr)


def _print(text: str) -> None:
    from mpi4py import MPI

    if MPI.COMM_WORLD.rank == 0:
        print(text, flush=True)


def _cmd_mesh(args) -> int:
    from .mesh_command import cmd_mesh

    return cmd_mesh(args)


def cmd_scenes(args) -> int:
    """List built-in scenes, one line each."""
    from .scene import available_scenes, load_scene

    for name in available_scenes():
        scene = load_scene(name)
        _print(f"{name:28s} {scene.summary}")
    return 0


def _prepare(args):
    from .api import check_method
    from .scene import load_scene
    from .solver import linear_solver_options

    scene = load_scene(args.scene).with_overrides(args.sets)
    if getattr(args, "method", None):
        check_method(args.method)
    scene.level(args.level)
    return scene, linear_solver_options(args.linear_solver)


def cmd_run(args) -> int:
    """Run one scene with one method."""
    from .api import RunFailed, run

    scene, options = _prepare(args)
    try:
        result = run(
            scene, args.method, args.level, args.out, solver_options=options, make_parents=False
        )
    except RunFailed as err:
        raise _SolverFailure(str(err)) from err
    _print(_probe_lines(result.data))
    _print(f"results: {result.folder}")
    return 0


def _probe_lines(summary: dict) -> str:
    res = summary["resources"]
    lines = [
        f"{summary['scene']} / {summary['method']} / {summary['level']}: "
        f"CPU {res['cpu_s']:.2f} s, wall {res['wall_s']:.2f} s, "
        f"peak memory {res['peak_rss_mb']:.0f} MB, {summary.get('dofs')} DOFs, "
        f"{res['ranks']} rank(s)"
    ]
    for name, value in summary["probes"].items():
        unit = summary.get("probe_units", {}).get(name) or ""
        lines.append(
            f"  {name:28s} {value:.6g} {unit}"
            if isinstance(value, float)
            else f"  {name:28s} {value} {unit}"
        )
    return "\n".join(lines)


def cmd_compare(args) -> int:
    """Compare two finished runs; write comparison.json and figures."""
    from mpi4py import MPI

    from .results import OutputDir, load_summary

    comm = MPI.COMM_WORLD
    ref, other = load_summary(args.ref), load_summary(args.other)
    with OutputDir(args.out, comm) as out:
        report = write_comparison(ref, other, out.path, comm)
    _print(_comparison_lines(report))
    _print(f"comparison: {args.out}")
    return 0


def write_comparison(ref: dict, other: dict, folder: Path, comm) -> dict:
    """Metrics + figures of ``other`` against ``ref`` into ``folder`` (rank 0 writes)."""
    from .compare import compare_summaries
    from .results import atomic_write_json

    report = compare_summaries(ref, other)
    if comm.rank == 0:
        from . import plots

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


def cmd_bench(args) -> int:
    """Run both methods, then write report.json, report.md and figures."""
    from mpi4py import MPI

    from .api import RunFailed, check_scene_methods, run
    from .compare import resources_table
    from .results import OutputDir, atomic_write_json

    comm = MPI.COMM_WORLD
    scene, options = _prepare(args)
    check_scene_methods(scene)  # both methods, before anything runs
    with OutputDir(args.out, comm) as out:
        runs = {}
        for method in ("coupled", "decoupled"):
            try:
                runs[method] = run(
                    scene, method, args.level, out.path / method, comm=comm, solver_options=options
                ).data
            except RunFailed as err:
                out.commit()
                raise _SolverFailure(str(err)) from err
        if scene.family == "shoulder":
            return _shoulder_report(args, scene, runs, out, comm)
        report = write_comparison(runs["coupled"], runs["decoupled"], out.path, comm)
        report["speedup_cpu"] = report["resources"]["speedup_cpu"]
        report["memory_ratio"] = report["resources"]["memory_ratio"]
        table = resources_table(runs)
        if comm.rank == 0:
            atomic_write_json(out.path / "report.json", report)
            md = [
                f"# {scene.name}: coupled against decoupled ({args.level or scene.default_level})",
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
            (out.path / "report.md").write_text("\n".join(md))
    _print(_probe_lines(runs["coupled"]))
    _print(_probe_lines(runs["decoupled"]))
    _print(_comparison_lines(report))
    _print(table)
    _print(f"report: {args.out / 'report.md'}")
    return 0


def _shoulder_report(args, scene, runs: dict, out, comm) -> int:
    """The shoulder study's report (paper figures, Table II) from the two runs."""
    from .shoulder_report import comparison_table, write_report

    level = args.level or scene.default_level
    table = None
    if comm.rank == 0:
        report = write_report(out.path / "coupled", out.path / "decoupled", out.path, level)
        table = comparison_table(report)
    table = comm.bcast(table, root=0)
    for method, data in runs.items():
        if data.get("status") != "ok":
            _print(f"{method}: {data.get('status')}: {data.get('message')}")
    _print(table)
    _print(f"report: {args.out / 'report.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
