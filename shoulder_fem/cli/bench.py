"""``shoulder-fem bench``: both methods on one scene, then the family's report.

Serial, each method runs as ``shoulder-fem run`` in a process of its own (each peak memory is
its own). A bench stopped (SIGTERM, Ctrl-C, a failed run) after a method finished keeps that
method's folder: ``OUT`` then holds it and ``bench.json`` with ``"status": "incomplete"``, and
``bench --resume`` reuses it when the request is the same (scene, level, parameters, linear
solver, ranks and the code itself, by a digest of the package's sources).
"""

from __future__ import annotations

import functools
import hashlib
import json
import shutil
import subprocess
import sys
from pathlib import Path

from shoulder_fem.cli.args import petsc_options
from shoulder_fem.cli.commands import (
    EXIT_INPUT,
    SolverFailure,
    generic_report,
    prepare,
    raise_unless_finished,
    say,
)

#: What ``OUT/bench.json`` is called (also a result file: a rerun may replace the folder).
BENCH_NAME = "bench.json"


@functools.lru_cache(maxsize=1)
def code_digest() -> str:
    """SHA-256 of the package's Python and C sources and scene files (what decides the results).

    The packages are located, not imported (``forms`` and ``meshes`` live in folders of their
    own in a source checkout).
    """
    import importlib.util

    digest = hashlib.sha256()
    for name in ("shoulder_fem", "shoulder_fem.forms", "shoulder_fem.meshes"):
        root = Path(importlib.util.find_spec(name).origin).parent
        for path in sorted(root.rglob("*")):
            if path.suffix in (".py", ".toml", ".c") and "__pycache__" not in path.parts:
                digest.update(str(path.relative_to(root)).encode())
                digest.update(path.read_bytes())
    return digest.hexdigest()


def bench_request(scene, level: str, args, ranks: int) -> dict:
    """Everything a finished method's results depend on (JSON-ready)."""
    from shoulder_fem.io.output import to_jsonable

    return {
        "scene": scene.name,
        "level": level,
        "parameters": to_jsonable(scene.values()),
        "linear_solver": args.linear_solver,
        "ranks": ranks,
        "code": code_digest(),
    }


def reusable_runs(out: Path, request: dict) -> dict[str, Path]:
    """The finished methods' folders of an earlier bench into ``out`` made for ``request``."""
    from shoulder_fem.io.results import load_summary

    try:
        state = json.loads((out / BENCH_NAME).read_text())
    except (OSError, ValueError):
        return {}
    if state.get("request") != request:
        return {}
    found = {}
    for method in state.get("finished", []):
        try:
            if load_summary(out / method).get("status") == "ok":
                found[method] = out / method
        except (OSError, ValueError):
            continue
    return found


def cmd_bench(args) -> int:
    """Run both methods, then write the family's report (report.json, report.md, figures)."""
    from mpi4py import MPI

    from shoulder_fem.api import METHODS, scene_family
    from shoulder_fem.families.base import BenchReport
    from shoulder_fem.io.output import OutputDir, atomic_write_json

    comm = MPI.COMM_WORLD
    scene, options = prepare(args)
    fam = scene_family(scene)  # both methods, before anything runs
    scene = fam.resolved(scene)
    level = args.level or scene.default_level
    if fam.check_bench is not None:
        fam.check_bench(scene, level)
    request = bench_request(scene, level, args, comm.size)
    reuse = reusable_runs(Path(args.out), request) if args.resume else {}
    if args.resume and not reuse:
        say(f"bench --resume: no finished run of this request in {args.out}; running both")
    # --resume continues the stopped bench in --out: that folder is meant to be replaced
    with OutputDir(args.out, comm, replace=args.force or args.resume) as out:
        runs = {}

        def save_state(status: str) -> None:  # rank 0 writes OUT/bench.json
            if comm.rank == 0:
                state = {"status": status, "finished": list(runs), "request": request}
                atomic_write_json(out.path / BENCH_NAME, state)

        try:
            for method in METHODS:
                runs[method] = _method(args, scene, options, method, out.path, reuse, comm)
        except SolverFailure:  # keep the failed run's completed steps, and what finished
            if runs or any((out.path / m).exists() for m in METHODS):
                save_state("incomplete")
                out.commit()
            raise  # nothing finished nor begun (e.g. the mesh failed): nothing is kept
        except BaseException:
            if runs and comm.size == 1:  # keep what finished (serial: no collective here)
                save_state("incomplete")
                out.commit()
                args.kept = sorted(runs)
            raise
        save_state("complete")
        bench = BenchReport(scene, level, runs, out.path, comm)
        text = (fam.report or generic_report)(bench)
    say(text)
    say(f"report: {args.out / 'report.md'}")
    for method, data in runs.items():  # compared over what it reached, and said: exit status 3
        raise_unless_finished(data, "bench", args.out / method)
    return 0


def _method(args, scene, options, method: str, staging: Path, reuse: dict, comm) -> dict:
    """One method's summary: reused from an earlier bench, or run (apart when serial)."""
    from shoulder_fem.api import RunFailed, run
    from shoulder_fem.io.results import load_summary

    folder = staging / method
    if method in reuse:
        if comm.rank == 0:
            shutil.copytree(reuse[method], folder)
        comm.Barrier()
        say(f"bench: {method}: reusing the finished run in {reuse[method]} (same request)")
        return load_summary(folder)
    try:
        if comm.size == 1:
            return _run_apart(args, method, folder)
        return run(
            scene,
            method,
            args.level,
            folder,
            comm=comm,
            solver_options=options,
            petsc_options=petsc_options(args.petsc),
        ).data
    except RunFailed as err:
        raise SolverFailure(str(err)) from err


def _run_apart(args, method: str, folder: Path) -> dict:
    """``shoulder-fem run`` of one method in a process of its own; its summary.

    Serial ``bench`` runs each method apart, so that each one's peak memory is its own: in one
    process the second method started with what the first had left (measured at ``paper``:
    the decoupled run's peak 573 MB after the coupled run, 537 MB alone). A stopped ``bench``
    (SIGTERM) stops the child too.

    Raises:
        RunFailed: The run failed (its summary says where); the child printed why.
        SolverFailure: The child ended otherwise without a summary (its status named).
    """
    from shoulder_fem.api import Result, RunFailed

    cmd = [sys.executable, "-m", "shoulder_fem.cli"]
    cmd += ["-q"] if args.quiet else ["-v"] * max(args.verbose - 1, 0)
    cmd += ["run", str(args.scene), "--method", method, "--out", str(folder)]
    cmd += [] if args.linear_solver is None else ["--linear-solver", args.linear_solver]
    cmd += [] if args.level is None else ["--level", args.level]
    for item in args.sets:
        cmd += ["--set", item]
    for item in args.petsc:
        cmd += ["--petsc", item]
    child = subprocess.Popen(cmd)
    try:
        status = child.wait()
    finally:
        if child.poll() is None:  # interrupted here: stop the child, which cleans up
            child.terminate()
            child.wait()
    if (folder / "summary.json").is_file():
        result = Result.load(folder)
        if status == 0 or result.data.get("status") == "incomplete":  # the bench compares it
            return result.data
        raise RunFailed(f"{method}: {result.data.get('message')}", result)
    if status == EXIT_INPUT:  # the child refused its input and printed which and why
        from shoulder_fem.scene import SceneError

        raise SceneError(f"bench: the {method} run refused its input (above); nothing was run")
    raise SolverFailure(f"bench: the {method} run ended with exit status {status}, no results")
