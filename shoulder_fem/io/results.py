"""The output folder of a run: atomic creation, ``summary.json`` and XDMF fields.

A run writes everything into a staging folder ``<final>.partial-<token>`` next to the requested
output folder and renames it to ``<final>`` only when it commits, so a reader never sees half a
result, and a crashed run leaves no folder that looks like one:

>>> with OutputDir(Path("results/demo"), comm) as out:
...     rec = Recorder(comm, out)
...     mon = ResourceMonitor(comm, scratch_dir=out.scratch)
...     ...
...     rec.write_summary(mon.finish(out.path), mon.stages)

``summary.json`` (layout in ARCHITECTURE, "Interfaces") is written by rank 0 only; fields for
ParaView go to ``<out>/fields/<name>.xdmf`` through :class:`FieldWriter`. Every value in the
files is in SI units, with the unit stated next to it.
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime
import json
import logging
import math
import os
import secrets
import shutil
import tempfile
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path, PurePath
from types import TracebackType
from typing import TYPE_CHECKING, Any, BinaryIO

import numpy as np

if TYPE_CHECKING:
    import dolfinx.fem
    import dolfinx.mesh
    from mpi4py import MPI

__all__ = [
    "FieldWriter",
    "OutputDir",
    "OutputError",
    "Recorder",
    "SUMMARY_NAME",
    "atomic_savez",
    "atomic_write_bytes",
    "atomic_write_json",
    "atomic_write_text",
    "load_summary",
    "to_jsonable",
]

logger = logging.getLogger(__name__)

SUMMARY_NAME = "summary.json"
"""File name of a run's summary inside its output folder; its presence marks a folder as ours."""


class OutputError(ValueError):
    """The output folder cannot be used; the message names the path and the reason."""


# --------------------------------------------------------------------------------------------
# JSON
# --------------------------------------------------------------------------------------------


def to_jsonable(obj: Any) -> Any:
    """Convert a value to plain JSON types.

    numpy scalars and arrays become Python numbers and (nested) lists, tuples become lists,
    paths become strings, dataclass instances become dicts; non-finite floats (NaN, ±inf) become
    None (JSON ``null``).

    Args:
        obj: value to convert.

    Returns:
        An equivalent value made of dict, list, str, int, float, bool and None.

    Raises:
        TypeError: for values with no JSON form (e.g. arbitrary objects, complex numbers).
    """
    if obj is None or isinstance(obj, (bool, str)):
        return obj
    if isinstance(obj, int):
        return int(obj)
    if isinstance(obj, float):
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, np.generic):
        return to_jsonable(obj.item())
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, Mapping):
        out = {}
        for key, value in obj.items():
            if isinstance(key, np.generic):
                key = key.item()
            if not isinstance(key, (str, int, float, bool)):
                raise TypeError(f"cannot use a {type(key).__name__} as a JSON key: {key!r}")
            out[str(key)] = to_jsonable(value)
        return out
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, PurePath):
        return str(obj)
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return to_jsonable(dataclasses.asdict(obj))
    raise TypeError(f"cannot convert a {type(obj).__name__} to JSON: {obj!r}")


def _fsync_dir(folder: Path) -> None:
    """Flush a folder's entries (renames) to disk where the platform allows it."""
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def atomic_write_bytes(path: str | os.PathLike[str], write: Callable[[BinaryIO], None]) -> None:
    """Write a file so that readers see either the old file or the complete new one.

    ``write(f)`` fills a temporary file in the same folder, which is flushed to disk, made
    readable like the rest of the output (0644) and renamed over ``path``. On any error no
    temporary file is left behind and an existing ``path`` is untouched. No MPI inside: the
    caller writes on one rank only. The one way this package writes a file atomically.
    """
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    _fsync_dir(path.parent)


def atomic_write_text(path: str | os.PathLike[str], text: str) -> None:
    """Write UTF-8 text atomically (see :func:`atomic_write_bytes`)."""
    atomic_write_bytes(path, lambda f: f.write(text.encode("utf-8")))


def atomic_write_json(path: str | os.PathLike[str], data: Any) -> None:
    """Write JSON atomically (see :func:`atomic_write_bytes`).

    The data are converted with :func:`to_jsonable` first (NaN/inf become null).

    Raises:
        TypeError: if ``data`` holds a value with no JSON form.
    """
    atomic_write_text(path, json.dumps(to_jsonable(data), indent=2, allow_nan=False) + "\n")


def atomic_savez(path: str | os.PathLike[str], arrays: Mapping[str, Any]) -> None:
    """Write NumPy arrays to an ``.npz`` file atomically (see :func:`atomic_write_bytes`)."""
    atomic_write_bytes(path, lambda f: np.savez(f, **arrays))


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


# --------------------------------------------------------------------------------------------
# Output folder
# --------------------------------------------------------------------------------------------


def _check_final(final: Path) -> str | None:
    """Why ``final`` cannot become an output folder, or None if it can."""
    parent = final.parent
    if not final.name or final.name in (".", ".."):
        return "not a folder name"
    if not parent.exists():
        return f"parent folder {parent} does not exist"
    if not parent.is_dir():
        return f"parent {parent} is not a folder"
    if not os.access(parent, os.W_OK | os.X_OK):
        return f"parent folder {parent} is not writable"
    if final.is_symlink():
        return "is a symbolic link; give the real folder"
    if final.exists():
        if not final.is_dir():
            return "exists and is not a folder"
        if any(final.iterdir()) and not (final / SUMMARY_NAME).is_file():
            return (
                f"is a non-empty folder without {SUMMARY_NAME} (not a shoulder-fem result); "
                "refusing to replace it"
            )
    return None


class OutputDir:
    """An output folder that appears complete or not at all.

    Construction (collective) validates ``final`` and creates the staging folder
    ``<final>.partial-<token>`` with a ``scratch`` folder inside; the run writes into
    :attr:`path`. :meth:`commit` renames the staging folder to ``final``, replacing a previous
    shoulder-fem result there (a folder holding ``summary.json``); :meth:`abort` removes it.

    As a context manager it commits on normal exit and aborts on an exception, unless the caller
    has already committed (e.g. to keep the steps before a diverged solve readable before
    re-raising). Either way no ``.partial-*`` folder is left behind.

    Args:
        final: the folder the results should end up in (``--out``).
        comm: the run's communicator.

    Raises:
        OutputError: on every rank, if the parent of ``final`` does not exist or is not writable,
            or ``final`` exists and is neither empty nor a previous shoulder-fem result.
    """

    def __init__(self, final: Path, comm: MPI.Comm) -> None:
        self.comm = comm
        self.final = Path(final).expanduser().absolute()
        reply: tuple[str | None, str | None] = (None, None)
        if comm.rank == 0:
            reason = _check_final(self.final)
            if reason is not None:
                reply = (None, f"--out {self.final}: {reason}")
            else:
                token = secrets.token_hex(4)
                staging = self.final.parent / f"{self.final.name}.partial-{token}"
                try:
                    staging.mkdir()
                    (staging / "scratch").mkdir()
                    reply = (token, None)
                except OSError as exc:
                    shutil.rmtree(staging, ignore_errors=True)
                    reply = (None, f"--out {self.final}: cannot create {staging}: {exc.strerror}")
        token, error = comm.bcast(reply, root=0)
        if error is not None:
            raise OutputError(error)
        self.token: str = token
        self._staging = self.final.parent / f"{self.final.name}.partial-{token}"
        self._state = "open"

    @property
    def path(self) -> Path:
        """The staging folder: everything of the run is written here until :meth:`commit`."""
        return self._staging

    @property
    def scratch(self) -> Path:
        """Folder for temporary files, shared by all ranks; removed at :meth:`commit`."""
        return self._staging / "scratch"

    @property
    def state(self) -> str:
        """``"open"``, ``"committed"``, ``"aborted"`` or ``"failed"`` (commit failed)."""
        return self._state

    def field_file(self, name: str) -> Path:
        """Path of the XDMF file ``<path>/fields/<name>.xdmf`` for :class:`FieldWriter`."""
        return self.path / "fields" / f"{name}.xdmf"

    def commit(self) -> Path:
        """Publish the results under the final name (collective; a no-op after a commit).

        All ranks synchronise (every file must be closed before), then rank 0 removes the
        scratch folder and renames the staging folder to ``final``. A previous result there is
        first renamed to a hidden trash name and deleted after the rename, so ``final`` is always
        either the old or the new complete result.

        Returns:
            The final folder.

        Raises:
            OutputError: on every rank, if the rename fails or ``final`` was filled with foreign
                files during the run; the staging folder is then kept and named in the message.
        """
        if self._state == "committed":
            return self.final
        if self._state != "open":
            raise OutputError(f"--out {self.final}: cannot commit, output is {self._state}")
        self.comm.Barrier()
        error = None
        if self.comm.rank == 0:
            try:
                self._commit_rank0()
            except (OSError, OutputError) as exc:
                error = f"--out {self.final}: commit failed ({exc}); results kept in {self.path}"
        error = self.comm.bcast(error, root=0)
        if error is not None:
            self._state = "failed"
            raise OutputError(error)
        self._state = "committed"
        return self.final

    def _commit_rank0(self) -> None:
        shutil.rmtree(self.scratch, ignore_errors=True)
        final = self.final
        trash = None
        if final.is_symlink() or final.exists():
            if final.is_symlink() or not final.is_dir():
                raise OutputError("the output path became a file or link during the run")
            if not any(final.iterdir()):
                final.rmdir()
            elif (final / SUMMARY_NAME).is_file():
                trash = final.parent / f".{final.name}.trash-{self.token}"
                os.rename(final, trash)
            else:
                raise OutputError("the output folder was filled with foreign files during the run")
        try:
            os.rename(self._staging, final)
        except OSError:
            if trash is not None:
                os.rename(trash, final)
            raise
        _fsync_dir(final.parent)
        if trash is not None:
            shutil.rmtree(trash, ignore_errors=True)
        logger.info("results written to %s", final)

    def abort(self) -> None:
        """Discard the staging folder (rank 0 removes it; a no-op after commit or abort).

        Uses no MPI communication, so it is safe on the exception path even when only some ranks
        raised: a collective there could hang the run instead of letting MPI abort it.
        """
        if self._state != "open":
            return
        self._state = "aborted"
        if self.comm.rank == 0:
            # Another rank may still be closing files inside: retry once if the folder refills.
            for _ in range(3):
                shutil.rmtree(self._staging, ignore_errors=True)
                if not self._staging.exists():
                    break

    def __enter__(self) -> OutputDir:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc_type is None:
            if self._state == "open":
                self.commit()
        else:
            self.abort()


# --------------------------------------------------------------------------------------------
# summary.json
# --------------------------------------------------------------------------------------------

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


# --------------------------------------------------------------------------------------------
# Fields
# --------------------------------------------------------------------------------------------


class FieldWriter:
    """Time series of fields in one XDMF/HDF5 file pair for ParaView (collective throughout).

    The mesh is written once at construction; :meth:`write` appends the given functions at a
    time. Each function appears under its ``name``.

    dolfinx 0.5.2's ``XDMFFile.write_function`` evaluates any Lagrange-type function (P1, P2,
    enriched, sub-functions ``u.sub(i)``) at the mesh's geometry nodes and writes DG0 functions,
    scalar, vector or tensor, as cell data; both were checked in serial and on 2 ranks (P2 values
    at the nodes agree with a P1 interpolation to round-off). So no interpolation is done here:
    a P2 displacement is shown at the vertices, a DG0 stress per cell. Mixed-element functions
    and quadrature functions are refused (write ``w.sub(i)``, or project to DG0, instead).

    Args:
        comm: communicator of the mesh.
        mesh: the mesh all written functions live on.
        path: the ``.xdmf`` file (the ``.h5`` goes next to it), e.g.
            ``out.field_file("bone")``; its folder is created if missing.
    """

    def __init__(self, comm: MPI.Comm, mesh: dolfinx.mesh.Mesh, path: Path) -> None:
        from dolfinx.io import XDMFFile

        self.comm = comm
        self.mesh = mesh
        self.path = Path(path).with_suffix(".xdmf")
        if comm.rank == 0:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        comm.Barrier()
        self._file = XDMFFile(comm, str(self.path), "w")
        self._file.write_mesh(mesh)
        self._times: dict[str, list[float]] = {}
        self._closed = False

    @staticmethod
    def _check_writable(u: dolfinx.fem.Function) -> None:
        import ufl

        element = u.function_space.ufl_element()
        if element.family() == "Quadrature":
            raise ValueError(f"field {u.name!r}: quadrature functions cannot be written to XDMF")
        if isinstance(element, ufl.MixedElement) and not isinstance(
            element, (ufl.VectorElement, ufl.TensorElement)
        ):
            raise ValueError(
                f"field {u.name!r} is on a mixed element; write its parts w.sub(i) instead"
            )

    def write(self, functions: Sequence[dolfinx.fem.Function], t: float) -> None:
        """Append the functions at time ``t`` (collective; same list and ``t`` on every rank).

        Args:
            functions: functions on this writer's mesh, with distinct names.
            t: the time (or load parameter) of this frame [s].

        Raises:
            ValueError: for a function on another mesh, duplicate names, a time not later than
                the previous frame of that function, or an element XDMF cannot hold.
        """
        if self._closed:
            raise ValueError(f"{self.path}: FieldWriter is closed")
        names = [u.name for u in functions]
        if len(set(names)) != len(names):
            raise ValueError(f"{self.path}: duplicate field names {names}")
        t = float(t)
        for u in functions:
            if u.function_space.mesh is not self.mesh:
                raise ValueError(f"field {u.name!r} is not on the mesh of {self.path}")
            self._check_writable(u)
            previous = self._times.get(u.name)
            if previous and t <= previous[-1]:
                raise ValueError(
                    f"field {u.name!r}: time {t} is not after the last written {previous[-1]}"
                )
        for u in functions:
            u.x.scatter_forward()
            self._file.write_function(u, t)
            self._times.setdefault(u.name, []).append(t)

    @property
    def times(self) -> dict[str, list[float]]:
        """The times written so far, per field name [s]."""
        return {k: list(v) for k, v in self._times.items()}

    def close(self) -> None:
        """Close the file (collective; idempotent)."""
        if not self._closed:
            self._file.close()
            self._closed = True

    def __enter__(self) -> FieldWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
