"""A run's ``summary.json``: the :class:`Recorder` that collects it, and :func:`load_summary`.

A run records into a :class:`Recorder` and writes the summary into its output folder
(:class:`~shoulder_fem.io.output.OutputDir`) before the folder commits:

>>> with OutputDir(Path("results/demo"), comm) as out:
...     rec = Recorder(comm, out)
...     mon = ResourceMonitor(comm, scratch_dir=out.scratch)
...     ...
...     rec.write_summary(mon.finish(out.path), mon.stages)

``summary.json`` (layout in ARCHITECTURE, "Interfaces") is written by rank 0 only. Every value
in it is in SI units, with the unit stated next to it.
"""

from __future__ import annotations

import datetime
import json
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from shoulder_fem.io.output import SUMMARY_NAME, OutputDir, atomic_write_json, to_jsonable

if TYPE_CHECKING:
    from mpi4py import MPI

__all__ = ["Recorder", "SOLVER_KEYS", "STATUSES", "load_summary"]


def load_summary(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read a run's ``summary.json``.

    Args:
        path: the output folder of a run, or the summary file itself.

    Returns:
        The summary as a dict (null values come back as None).

    Raises:
        FileNotFoundError: if there is no summary at ``path``.
    """
    p = Path(path)
    if p.is_dir():
        p = p / SUMMARY_NAME
    if not p.is_file():
        raise FileNotFoundError(f"no {SUMMARY_NAME} at {path} (not a shoulder-fem result?)")
    with open(p, encoding="utf-8") as f:
        return json.load(f)


SOLVER_KEYS = ("steps", "newton_iterations", "linear_solves", "factorizations", "cutbacks")
"""Counters of :attr:`Recorder.solver_stats`."""

STATUSES = ("ok", "failed", "incomplete")
"""Allowed values of a run's status."""

_RESERVED = frozenset(
    {
        "version",
        "created",
        "scene",
        "method",
        "level",
        "status",
        "message",
        "ranks",
        "parameters",
        "parameter_units",
        "resources",
        "stages",
        "solver",
        "series",
        "probes",
        "probe_units",
    }
)


class Recorder:
    """Collects what a run reports and writes it as ``summary.json``.

    Every rank may call every method (values should agree across ranks; rank 0's are written).
    Values are converted to JSON types on entry (see :func:`to_jsonable`), so a value that cannot
    be written fails where it is recorded. Units are SI and stated as strings, e.g. ``"Pa"``,
    ``"m"``, ``"rad/s"``; ``"1"`` for dimensionless values.

    Args:
        comm: the run's communicator.
        out: the run's output folder (or a plain folder path).
    """

    def __init__(self, comm: MPI.Comm, out: OutputDir | Path) -> None:
        self.comm = comm
        self.out = out
        self.meta: dict[str, Any] = {"scene": None, "method": None, "level": None}
        self.status = "ok"
        self.message: str | None = None
        self.parameters: dict[str, Any] = {}
        self.parameter_units: dict[str, str] = {}
        self.probes: dict[str, Any] = {}
        self.probe_units: dict[str, str | None] = {}
        self.series: dict[str, dict[str, Any]] = {}
        self.solver_stats: dict[str, int] = dict.fromkeys(SOLVER_KEYS, 0)
        self.extras: dict[str, Any] = {}

    @property
    def folder(self) -> Path:
        """The folder ``summary.json`` goes to."""
        return self.out.path if isinstance(self.out, OutputDir) else Path(self.out)

    def set_meta(
        self, *, scene: str | None = None, method: str | None = None, level: str | None = None
    ) -> None:
        """Set what was run (only the arguments given are changed)."""
        for key, value in (("scene", scene), ("method", method), ("level", level)):
            if value is not None:
                self.meta[key] = str(value)

    def set_parameter(self, name: str, value: Any, unit: str) -> None:
        """Record a run parameter with its unit (SI; ``"1"`` if dimensionless)."""
        self.parameters[name] = to_jsonable(value)
        self.parameter_units[name] = str(unit)

    def set_parameters(self, values: Mapping[str, Any], units: Mapping[str, str]) -> None:
        """Record several parameters; every value needs a unit.

        Raises:
            ValueError: if ``units`` lacks a unit for some value.
        """
        missing = sorted(set(values) - set(units))
        if missing:
            raise ValueError(f"parameters without a unit: {', '.join(missing)}")
        for name, value in values.items():
            self.set_parameter(name, value, units[name])

    def set_probe(self, name: str, value: Any, unit: str | None = None) -> None:
        """Record a scalar (or small array) result, SI units."""
        self.probes[name] = to_jsonable(value)
        self.probe_units[name] = unit

    def _series(self, name: str, x_unit: str, y_unit: str) -> dict[str, Any]:
        entry = self.series.setdefault(
            name, {"x": [], "y": [], "x_unit": str(x_unit), "y_unit": str(y_unit)}
        )
        if (entry["x_unit"], entry["y_unit"]) != (x_unit, y_unit):
            raise ValueError(
                f"series {name!r} has units ({entry['x_unit']}, {entry['y_unit']}), "
                f"not ({x_unit}, {y_unit})"
            )
        return entry

    def add_series_point(self, name: str, x: Any, y: Any, x_unit: str, y_unit: str) -> None:
        """Append one point (e.g. one time step) to a history; units must match earlier points."""
        entry = self._series(name, x_unit, y_unit)
        entry["x"].append(to_jsonable(x))
        entry["y"].append(to_jsonable(y))

    def set_series(
        self, name: str, x: Sequence[Any], y: Sequence[Any], x_unit: str, y_unit: str
    ) -> None:
        """Set a whole history at once (replaces an earlier one of that name).

        Raises:
            ValueError: if ``x`` and ``y`` differ in length.
        """
        xs, ys = to_jsonable(list(x)), to_jsonable(list(y))
        if len(xs) != len(ys):
            raise ValueError(f"series {name!r}: {len(xs)} x values but {len(ys)} y values")
        self.series[name] = {"x": xs, "y": ys, "x_unit": str(x_unit), "y_unit": str(y_unit)}

    def count(self, key: str, n: int = 1) -> None:
        """Add ``n`` to a solver counter (one of :data:`SOLVER_KEYS`).

        Raises:
            KeyError: for an unknown counter (catches typos).
        """
        if key not in self.solver_stats:
            raise KeyError(f"unknown solver counter {key!r}; known: {', '.join(SOLVER_KEYS)}")
        self.solver_stats[key] += int(n)

    def add_solver_counts(self, solver: Any = None, stepper: Any = None) -> None:
        """Add a solver's and a load stepper's counters to the run's (the one way to do it).

        Args:
            solver: counters of the solves (a ``SolveStats``: ``newton_iterations``,
                ``linear_solves``, ``factorizations``), or None.
            stepper: counters of the stepping (``steps``, ``cutbacks``), or None.
        """
        if stepper is not None:
            self.count("steps", stepper.steps)
            self.count("cutbacks", stepper.cutbacks)
        if solver is not None:
            self.count("newton_iterations", solver.newton_iterations)
            self.count("linear_solves", solver.linear_solves)
            self.count("factorizations", solver.factorizations)

    def set_status(self, status: str, message: str | None = None) -> None:
        """Set the run's outcome, with a one-line reason.

        ``"ok"``, ``"failed"`` or ``"incomplete"`` (stopped early, its completed steps kept).
        """
        if status not in STATUSES:
            raise ValueError(f"status must be one of {STATUSES}, not {status!r}")
        self.status = status
        self.message = message

    def extra(self, key: str, value: Any) -> None:
        """Record any other top-level entry (e.g. ``"blas"``, ``"dofs"``, ``"comparison"``).

        Raises:
            ValueError: if ``key`` is one of the summary's own keys.
        """
        if key in _RESERVED:
            raise ValueError(f"{key!r} is a reserved summary key; use its own setter")
        self.extras[key] = to_jsonable(value)

    def summary(
        self,
        resources: Mapping[str, Any] | None = None,
        stages: Sequence[Mapping[str, Any]] | None = None,
    ) -> dict[str, Any]:
        """The summary as a dict of JSON types (no I/O)."""
        from shoulder_fem import __version__

        data: dict[str, Any] = {
            "version": __version__,
            "created": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
            **self.meta,
            "status": self.status,
            "message": self.message,
            "ranks": self.comm.size,
            "parameters": self.parameters,
            "parameter_units": self.parameter_units,
            "resources": dict(resources or {}),
            "stages": [dict(s) for s in stages or []],
            "solver": self.solver_stats,
            "series": self.series,
            "probes": self.probes,
            "probe_units": self.probe_units,
            **self.extras,
        }
        return to_jsonable(data)

    def write_summary(
        self,
        resources: Mapping[str, Any],
        stages: Sequence[Mapping[str, Any]],
    ) -> dict[str, Any]:
        """Write ``summary.json`` into the output folder (rank 0 writes; no collective inside).

        Args:
            resources: from :meth:`ResourceMonitor.finish`.
            stages: from :attr:`ResourceMonitor.stages`.

        Returns:
            The summary written, on every rank.
        """
        data = self.summary(resources, stages)
        if self.comm.rank == 0:
            atomic_write_json(self.folder / SUMMARY_NAME, data)
        return data
