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
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from mpi4py import MPI

from .scene import Scene, SceneError, load_scene

logger = logging.getLogger(__name__)

METHODS = ("coupled", "decoupled")


@dataclass(frozen=True)
class Family:
    """How a scene family is built and run by each method."""

    build: Callable  # (scene, level, comm) -> model
    methods: dict[str, Callable]  # method -> run(model, recorder, monitor, fields_dir, options)
    dofs: Callable  # model -> number of displacement DOFs (global)
    #: build takes the method too: (scene, level, comm, method) (each method meshes its own)
    method_build: bool = False


def _families() -> dict[str, Family]:
    from . import driven_body, hertz, shoulder, tied_block, tumbling
    from .methods import coupled, decoupled

    def driven_dofs(model) -> int:
        V = driven_body.vector_space(model)
        return V.dofmap.index_map.size_global * V.dofmap.index_map_bs

    return {
        "driven-body": Family(
            build=driven_body.build_driven_body,
            methods={
                "coupled": coupled.run_driven_body,
                "decoupled": decoupled.run_driven_body,
            },
            dofs=driven_dofs,
        ),
        "tumbling-body": tumbling.family(),
        "tied-block": tied_block.family(),
        "hertz": hertz.family(),
        "shoulder": shoulder.family(),
    }


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
        from .results import load_summary

        return cls(load_summary(folder), Path(folder))


def _make_parent(out: Path, comm: MPI.Comm) -> None:
    """Create ``out``'s parent folders on rank 0; every rank raises the same error on failure."""
    from .results import OutputError

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


def check_scene_methods(scene: Scene, methods: tuple[str, ...] = METHODS) -> None:
    """Raise :class:`SceneError` unless ``scene``'s family runs every one of ``methods``."""
    families = _families()
    if scene.family not in families:
        raise SceneError(f"{scene.source}: unknown scene family '{scene.family}'")
    missing = [m for m in methods if m not in families[scene.family].methods]
    if missing:
        raise SceneError(
            f"{scene.source}: scene '{scene.name}' has no {' or '.join(missing)} method "
            f"(it has: {', '.join(families[scene.family].methods)})"
        )


def run(
    scene: Scene | str,
    method: str,
    level: str | None = None,
    out: str | Path = "results/run",
    comm: MPI.Comm = MPI.COMM_WORLD,
    solver_options: dict | None = None,
    make_parents: bool = True,
) -> Result:
    """Run ``scene`` with ``method`` ("coupled" or "decoupled") and write ``out``.

    Everything is checked before anything is solved or written: an unknown scene, method,
    level or parameter, or an unusable output folder raises :class:`SceneError` /
    ``OutputError`` (both ``ValueError``) and leaves nothing behind. A solver failure writes
    the completed steps with ``status = "failed"`` and raises :class:`RunFailed`.
    ``make_parents`` creates the parent folders of ``out`` (the CLI turns it off, so that a
    mistyped ``--out`` is an error rather than a new tree of folders).

    Returns:
        The run's summary.
    """
    from .resources import ResourceMonitor, blas_library, thread_settings
    from .results import OutputDir, Recorder
    from .solver import ConvergenceError

    if isinstance(scene, str | Path):
        scene = load_scene(scene)
    check_method(method)
    families = _families()
    if scene.family not in families:
        raise SceneError(f"{scene.source}: unknown scene family '{scene.family}'")
    family = families[scene.family]
    check_scene_methods(scene, (method,))
    level = level or scene.default_level
    scene.level(level)  # unknown level → SceneError now
    out = Path(out)
    if make_parents:
        _make_parent(out, comm)
    with OutputDir(out, comm) as outdir:
        monitor = ResourceMonitor(comm, outdir.scratch)
        recorder = Recorder(comm, outdir)
        recorder.set_meta(scene=scene.name, method=method, level=level)
        recorder.set_parameters(scene.values(), scene.units())
        recorder.extra("blas", blas_library())
        recorder.extra("threads", thread_settings())
        with monitor.stage("mesh"):
            if family.method_build:
                model = family.build(scene, level, comm, method)
            else:
                model = family.build(scene, level, comm)
        recorder.extra("dofs", family.dofs(model))
        logger.info(
            "%s / %s / %s: %d DOFs on %d rank(s)",
            scene.name,
            method,
            level,
            family.dofs(model),
            comm.size,
        )
        fields = outdir.path / "fields"
        if comm.rank == 0:
            fields.mkdir(exist_ok=True)
        comm.Barrier()
        failure = None
        try:
            with monitor.stage(method):
                family.methods[method](model, recorder, monitor, fields, solver_options)
        except ConvergenceError as err:
            recorder.set_status("failed", str(err))
            failure = err
            logger.error("%s", err)
        data = recorder.write_summary(monitor.finish(outdir.path), monitor.stages)
        final = outdir.commit()
    result = Result(data, Path(final))
    if failure is not None:
        raise RunFailed(f"{failure} (steps before it are in {final})", result) from failure
    return result
