"""The Python API for drivers: load a scene, change parameters, run a method, read the results.

    from shoulder_fem import load_scene, run
    scene = load_scene("spinning-bar").with_values(spin_rate=50.0)
    result = run(scene, "decoupled", level="coarse", out="out/bar-decoupled")
    print(result.probes["root_axial_stress"], result.resources["cpu_s"])

Works the same under ``mpirun -n N python driver.py`` (every rank calls :func:`run`; the
output folder is written once).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

from mpi4py import MPI

from shoulder_fem.families import family, family_names
from shoulder_fem.families.base import Family, RunContext
from shoulder_fem.scene import Scene, SceneError, load_scene

logger = logging.getLogger(__name__)

METHODS = ("coupled", "decoupled")


class RunFailed(RuntimeError):
    """A run stopped on a solver failure; its output folder holds the completed steps."""

    def __init__(self, message: str, summary: Result):
        super().__init__(message)
        self.summary = summary


@dataclass(frozen=True)
class Result:
    """A finished run's ``summary.json`` as attributes (``probes``, ``series``, ...)."""

    data: dict
    folder: Path

    def __getattr__(self, key: str):
        try:
            return self.__dict__["data"][key]
        except KeyError:
            raise AttributeError(key) from None

    @classmethod
    def load(cls, folder: str | Path) -> Result:
        """Read a run's output folder."""
        from shoulder_fem.io.results import load_summary

        return cls(load_summary(folder), Path(folder))


def _make_parent(out: Path, comm: MPI.Comm) -> None:
    """Create ``out``'s parent folders on rank 0; every rank raises the same error on failure."""
    from shoulder_fem.io.output import OutputError

    error = None
    if comm.rank == 0:
        try:
            out.parent.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            error = f"--out {out}: cannot create its parent folder: {err.strerror or err}"
    error = comm.bcast(error, root=0)
    if error:
        raise OutputError(error)


def check_method(method: str) -> str:
    """Return ``method`` if it is known, else raise a clear :class:`SceneError`."""
    if method not in METHODS:
        raise SceneError(f"unknown method '{method}' (known: {', '.join(METHODS)})")
    return method


def scene_family(scene: Scene, methods: tuple[str, ...] = METHODS) -> Family:
    """``scene``'s family; :class:`SceneError` unless it is known and runs every ``methods``."""
    if scene.family not in family_names():
        raise SceneError(f"{scene.source}: unknown scene family '{scene.family}'")
    fam = family(scene.family)
    missing = [m for m in methods if m not in fam.methods]
    if missing:
        raise SceneError(
            f"{scene.source}: scene '{scene.name}' has no {' or '.join(missing)} method "
            f"(it has: {', '.join(fam.methods)})"
        )
    return fam


def run(
    scene: Scene | str,
    method: str,
    level: str | None = None,
    out: str | Path = "results/run",
    comm: MPI.Comm = MPI.COMM_WORLD,
    solver_options: dict | None = None,
    make_parents: bool = True,
    petsc_options: dict | None = None,
    replace: bool = False,
    part1_from: str | Path | None = None,
) -> Result:
    """Run ``scene`` with ``method`` ("coupled" or "decoupled") and write ``out``.

    Everything is checked before anything is solved or written: an unknown scene, method,
    level or parameter, or an unusable output folder raises :class:`SceneError` /
    ``OutputError`` (both ``ValueError``) and leaves nothing behind. A solver failure writes
    the completed steps with ``status = "failed"`` and raises :class:`RunFailed`.
    ``make_parents`` creates the parent folders of ``out`` (the CLI turns it off, so that a
    mistyped ``--out`` is an error rather than a new tree of folders). A previous result in
    ``out`` is replaced only with ``replace`` (the CLI's ``--force``); else ``OutputError``.

    PETSc options: ``solver_options`` (key -> value, no dash) go to the method's nonlinear
    solvers as the code's own options do (read once when a solver is set up); ``petsc_options``
    (the CLI's ``--petsc``) reach every PETSc solver of the run under its own prefix and stay
    readable for the whole run (``snes_monitor``, ``ksp_view``, ``mat_mumps_icntl_*`` at the
    factorization), win over the code's values, are listed in ``summary.json``
    (``petsc_options``) and an option no solver read is a warning and listed too
    (``petsc_options_unused``: misspelt, or for no solver of this run).

    ``part1_from``: a finished decoupled run whose part 1 this one takes (:func:`sweep`).

    Returns:
        The run's summary. Its ``status`` is ``"ok"``, or ``"incomplete"`` for a run that
        stopped short of its final angle (its completed steps kept, ``message`` naming the
        angle reached and the reason; the command line exits 3 then).
    """
    from shoulder_fem.io.output import OutputDir
    from shoulder_fem.io.resources import ResourceMonitor, blas_library, thread_settings
    from shoulder_fem.io.results import Recorder

    if isinstance(scene, str | Path):
        scene = load_scene(scene)
    check_method(method)
    fam = scene_family(scene, (method,))
    scene = fam.resolved(scene)  # the values it derives, recorded as run
    level = level or scene.default_level
    scene.level(level)  # unknown level → SceneError now
    part1_from = _part1_source(scene, method, level, part1_from)
    out = Path(out)
    if make_parents:
        _make_parent(out, comm)
    with OutputDir(out, comm, replace=replace) as outdir:
        monitor = ResourceMonitor(comm, outdir.scratch)
        recorder = Recorder(comm, outdir)
        recorder.set_meta(scene=scene.name, method=method, level=level)
        recorder.extra("level_settings", scene.level(level))  # e.g. the mesh sizes (m)
        recorder.set_parameters(scene.values(), scene.units())
        recorder.extra("blas", blas_library())
        recorder.extra("threads", thread_settings())
        with monitor.stage("mesh"):
            model = fam.build(scene, level, comm, method)
        dofs = fam.dofs(model)
        recorder.extra("dofs", dofs)
        logger.info(
            "%s / %s / %s: %d DOFs on %d rank(s)", scene.name, method, level, dofs, comm.size
        )
        fields = outdir.path / "fields"
        if comm.rank == 0:
            fields.mkdir(exist_ok=True)
        comm.Barrier()
        context = RunContext(recorder, monitor, fields, solver_options, part1_from)
        failure = _run_method(fam.methods[method], model, context, method, petsc_options, comm)
        data = recorder.write_summary(monitor.finish(outdir.path), monitor.stages)
        final = outdir.commit()
    result = Result(data, Path(final))
    if failure is not None:
        raise RunFailed(f"{failure} (steps before it are in {final})", result) from failure
    return result


def _part1_source(scene: Scene, method: str, level: str, folder) -> Path | None:
    """``folder`` (or None) checked as the part 1 of this run (before anything is written)."""
    if folder is None:
        return None
    folder = Path(folder)
    if method != "decoupled" or scene.family != "shoulder":
        raise SceneError(
            f"part1_from {folder}: only the shoulder's decoupled method takes a recorded part 1"
        )
    from shoulder_fem.families.shoulder.reuse import check_source, read_source

    check_source(scene, level, read_source(folder), f"--from {folder}")
    return folder.resolve()


def _run_method(function, model, context, method: str, petsc_options, comm):
    """Run a method's function with the user's PETSc options; its ConvergenceError or None."""
    from shoulder_fem.engine.solver import (
        ConvergenceError,
        clear_user_options,
        set_user_options,
        unused_user_options,
    )

    recorder = context.recorder
    failure = None
    set_user_options(petsc_options)
    try:
        with context.monitor.stage(method):
            function(model, context)
    except ConvergenceError as err:
        recorder.set_status("failed", str(err))
        failure = err
        logger.error("%s", err)
    finally:
        unused = unused_user_options() if petsc_options else []
        clear_user_options()
    if petsc_options:
        _report_petsc_options(recorder, petsc_options, unused, comm)
    return failure


def _report_petsc_options(recorder, options: dict, unused: list[str] | None, comm) -> None:
    """List the user's PETSc options in the summary; warn of those no solver read."""
    recorder.extra("petsc_options", {str(k).lstrip("-"): str(v) for k, v in options.items()})
    if unused is None:
        logger.warning("PETSc options: could not ask PETSc which ones were read")
        return
    recorder.extra("petsc_options_unused", unused)
    if unused and comm.rank == 0:
        logger.warning(
            "PETSc option(s) %s: read by no solver of this run (misspelt?)",
            ", ".join(f"-{k}" for k in unused),
        )


def _new_folder(out: Path, command: str, comm: MPI.Comm) -> None:
    """Create ``out`` and its parents (collective); SceneError if it exists already."""
    if comm.allreduce(out.exists(), op=MPI.LOR):
        raise SceneError(f"--out {out}: exists already (a {command} writes a new folder)")
    _make_parent(out, comm)
    comm.Barrier()
    if comm.rank == 0:
        out.mkdir()
    comm.Barrier()


def study(
    scene: Scene | str,
    settings: list[str],
    out: str | Path,
    method: str = "decoupled",
    level: str | None = None,
    comm: MPI.Comm = MPI.COMM_WORLD,
) -> dict:
    """One whole run of ``method`` per combination of values, any keys (:mod:`.studies`).

    ``settings``: ``key=v1,v2,...`` each, values as ``--set`` takes them (``muscle_alpha=
    0.06,0.12MPa`` is read as 0.06 Pa and 0.12 MPa: give each value its unit, or none for
    SI); the variants are all their combinations, each a run folder in ``out`` (a new
    folder), with ``study.json`` (values, status, CPU and wall time, memory and series of
    every variant) and ``study.png`` / ``study.pdf``. Every variant is checked before the
    first is solved. A variant that stops short (``incomplete``) or fails is recorded and the
    next one runs.

    Returns:
        The contents of ``study.json``; ``data["finished"]`` is False when a variant did not
        reach its final angle (the command line then exits 3).

    Raises:
        SceneError: A malformed setting, an unknown key, a bad value, or ``out`` exists.
    """
    from shoulder_fem import studies as st
    from shoulder_fem.io.output import variant_folder

    if isinstance(scene, str | Path):
        scene = load_scene(scene)
    check_method(method)
    scene_family(scene, (method,))
    level = level or scene.default_level
    scene.level(level)
    variants = st.plan(scene, settings)
    out = Path(out)
    _new_folder(out, "study", comm)
    rows = []
    for i, (values, scene_v) in enumerate(variants):
        name = variant_folder(i, values)
        logger.info("study: variant %d of %d: %s", i + 1, len(variants), ", ".join(values))
        try:
            result = run(scene_v, method, level, out / name, comm)
        except RunFailed as err:
            result = err.summary
        rows.append(st.row(values, name, result.data))
        logger.info(
            "study: %s: %s, CPU %.1f s", ", ".join(values), rows[-1]["status"], rows[-1]["cpu_s"]
        )
    data = {
        "scene": scene.name,
        "method": method,
        "level": level,
        "keys": [s.partition("=")[0].strip() for s in settings],
        "finished": all(r["status"] == "ok" for r in rows),
        "variants": rows,
    }
    if comm.rank == 0:
        st.write_study(data, out)
    comm.Barrier()
    return data


def sweep(
    scene: Scene | str,
    source: str | Path,
    settings: list[str],
    out: str | Path,
    comm: MPI.Comm = MPI.COMM_WORLD,
) -> dict:
    """Part 2 again for every combination of swept values, from one decoupled run's part 1.

    ``source``: a finished decoupled run of ``scene``; ``settings``: ``key=v1,v2,...`` of the
    keys part 1 does not depend on (the scapula's material, its CT calibration, the rotation's
    duration, the stress recipe, part 2's solver:
    :data:`~shoulder_fem.families.shoulder.reuse.PART2_KEYS`). Every variant is checked before
    the first is solved; each is a decoupled run folder in ``out`` (a new folder), with
    ``sweep.json`` and ``sweep.png`` (the scapula's largest von Mises stress, over the bone and
    over the glenoid region, at every output angle, against the variants).

    Returns:
        The contents of ``sweep.json``.

    Raises:
        SceneError: A bad source, a key part 1 depends on, an unknown key or a bad value, or
            ``out`` exists.
        RunFailed: A variant's part 2 failed (the variants before it are kept).
    """
    from shoulder_fem.families.shoulder import sweep as sw
    from shoulder_fem.families.shoulder.model import reuse_meshes
    from shoulder_fem.io.output import variant_folder

    if isinstance(scene, str | Path):
        scene = load_scene(scene)
    source, out = Path(source).resolve(), Path(out)
    base, level, variants = sw.plan(scene, source, settings)
    _new_folder(out, "sweep", comm)
    rows = []
    with reuse_meshes(source):  # the source's scapula (or one meshing) for every variant
        for i, variant in enumerate(variants):
            name = variant_folder(i, variant)
            logger.info("sweep: variant %d of %d: %s", i + 1, len(variants), ", ".join(variant))
            scene_v = base.with_overrides(variant)
            result = run(scene_v, "decoupled", level, out / name, comm, part1_from=source)
            rows.append(sw.variant_row(variant, name, result, out / name))
    data = {
        "scene": scene.name,
        "level": level,
        "from": str(source),
        "keys": [s.partition("=")[0].strip() for s in settings],
        "glenoid_region_radius_m": sw.GLENOID_REGION,
        "variants": rows,
    }
    if comm.rank == 0:
        sw.write_sweep(data, out)
    comm.Barrier()
    return data
