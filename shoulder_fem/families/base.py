"""The contract between the orchestration and a scene family: :class:`Family`, :class:`RunContext`.

A family declares itself once, as a module-level ``FAMILY`` (listed in
:mod:`shoulder_fem.families`): how to build its model from a scene, one run function per
method, its DOF count, and optionally its own ``bench`` report.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Generic, TypeVar

if TYPE_CHECKING:
    from mpi4py import MPI

    from shoulder_fem.io.resources import ResourceMonitor
    from shoulder_fem.io.results import Recorder
    from shoulder_fem.scene import Scene

__all__ = ["BenchReport", "Family", "RunContext", "SolverOptions"]

ModelT = TypeVar("ModelT")

SolverOptions = Mapping[str, Any]
"""PETSc options (without prefix) that override a solver's defaults, e.g. ``{"ksp_type": "cg"}``."""


@dataclass(frozen=True)
class RunContext:
    """What a method's run function gets besides the model.

    Attributes:
        recorder: the run's summary (probes, series, counters, status).
        monitor: CPU time, memory and disk, with named stages.
        fields: the folder for ParaView fields (exists).
        options: PETSc options from the user for the method's solvers, or None.
        part1_from: A finished decoupled run whose part 1 this run's part 2 takes (a sweep
            over the bone: :mod:`shoulder_fem.families.shoulder.reuse`), or None.
    """

    recorder: Recorder
    monitor: ResourceMonitor
    fields: Path
    options: SolverOptions | None = None
    part1_from: Path | None = None


@dataclass(frozen=True)
class BenchReport:
    """What ``shoulder-fem bench`` gives a family's report hook.

    Attributes:
        scene: the scene both methods ran.
        level: the mesh level.
        runs: each method's ``summary.json`` contents, by method.
        folder: the bench output folder (each run in ``folder/<method>``).
        comm: the communicator (the hook is called on every rank).
    """

    scene: Scene
    level: str
    runs: Mapping[str, dict]
    folder: Path
    comm: MPI.Comm


@dataclass(frozen=True)
class Family(Generic[ModelT]):
    """How a scene family is built and run by each method.

    Attributes:
        name: the ``family`` of its scene files.
        build: ``build(scene, level, comm, method) -> model``; everything is checked here,
            before anything is solved (a family whose methods mesh differently uses ``method``).
        methods: ``run(model, context)`` per method name; results go to ``context.recorder``.
        dofs: the global number of displacement DOFs of a model.
        report: writes the ``bench`` report into ``BenchReport.folder`` and returns the text
            to print (rank 0's; other ranks may return anything); None: the generic one.
        check_bench: ``check_bench(scene, level)`` raises SceneError for a scene that ``bench``
            cannot compare (before anything runs); None: every scene can be.
        resolve: ``resolve(scene) -> scene`` with the values the family derives from others
            when they are not given (recorded in the summary as run); None: none.
    """

    name: str
    build: Callable[[Scene, str, MPI.Comm, str], ModelT]
    methods: Mapping[str, Callable[[ModelT, RunContext], None]]
    dofs: Callable[[ModelT], int]
    report: Callable[[BenchReport], str] | None = None
    check_bench: Callable[[Scene, str], None] | None = None
    resolve: Callable[[Scene], Scene] | None = None

    def resolved(self, scene: Scene) -> Scene:
        """``scene`` with the family's derived values (:attr:`resolve`)."""
        return self.resolve(scene) if self.resolve is not None else scene
