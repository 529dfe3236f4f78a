"""Writing output so that a reader never sees half of it: one file, or a run's whole folder.

One file goes through :func:`atomic_write_bytes` (and its text, JSON and ``.npz`` forms): a
temporary file renamed over the target. A run's folder is an :class:`OutputDir`: a staging
folder ``<final>.partial-<token>`` renamed to ``<final>`` only when the run commits, so a crashed
run leaves no folder that looks like a result. Values are converted to JSON by
:func:`to_jsonable` (SI units, NaN/inf as null).
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import math
import os
import re
import secrets
import shutil
import socket
import tempfile
import weakref
from collections.abc import Callable, Mapping
from pathlib import Path, PurePath
from types import TracebackType
from typing import TYPE_CHECKING, Any, BinaryIO

import numpy as np

if TYPE_CHECKING:
    from mpi4py import MPI

__all__ = [
    "OWNER_NAME",
    "OutputDir",
    "OutputError",
    "RESULT_FILES",
    "SUMMARY_NAME",
    "atomic_savez",
    "atomic_write_bytes",
    "atomic_write_json",
    "atomic_write_text",
    "is_result",
    "remove_stale_partials",
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


def variant_folder(i: int, values: list[str]) -> str:
    """The run folder of a sweep's or a study's variant ``i``: its number and values, file-safe."""
    return f"{i:02d}_" + re.sub(r"[^A-Za-z0-9_=.+-]+", "-", ",".join(values))[:80]


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


# --------------------------------------------------------------------------------------------
# Output folder
# --------------------------------------------------------------------------------------------

#: The output folders of this process not yet committed or aborted.
_OPEN: weakref.WeakSet = weakref.WeakSet()
#: Told the staging folders of :data:`_OPEN` whenever they change (rank 0's stop guard).
_WATCHERS: list[Callable[[list[str]], None]] = []


def watch_open_outputs(watcher: Callable[[list[str]], None]) -> Callable[[], None]:
    """Call ``watcher`` with the staging folders being written, now and at every change.

    Returns:
        The function that stops it.
    """
    _WATCHERS.append(watcher)
    _open_changed()
    return lambda: _WATCHERS.remove(watcher)


def _open_changed() -> None:
    paths = [str(out.path) for out in list(_OPEN)]
    for watcher in _WATCHERS:
        watcher(paths)


def _closed(out: OutputDir) -> None:
    """``out`` is no longer being written (committed, failed or aborted)."""
    _OPEN.discard(out)
    _open_changed()


def abort_open_outputs() -> None:
    """Discard every output folder still being written by this process.

    Rank 0 removes it; no MPI communication: for a process that must stop at once (SIGTERM
    under mpirun).
    """
    for out in list(_OPEN):
        out.abort()


#: In a staging folder: ``<host> <pid>`` of the process that writes it (rank 0).
OWNER_NAME = ".owner"


def _alive(pid: int) -> bool:
    """Whether process ``pid`` exists on this machine (one owned by another user counts)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_stale_partials(final: Path) -> list[Path]:
    """Remove the staging folders of ``final`` left by runs that died on this machine.

    A run killed outright (SIGKILL, out of memory, a node lost) cannot remove its
    ``<final>.partial-*`` folder. One whose owner (:data:`OWNER_NAME`) is a process of this
    host that no longer exists is removed; a folder of another host, or without an owner file,
    is left alone. A staging folder is made as ``.<final>.partial-*`` and renamed once its owner
    is written: one of those left by a run killed before the rename is removed the same way.
    Returns the folders removed.
    """
    removed = []
    host = socket.gethostname()
    hidden = final.parent.glob(f".{final.name}.partial-*")  # killed before their rename
    for staging in sorted([*final.parent.glob(f"{final.name}.partial-*"), *hidden]):
        try:
            owner_host, pid = (staging / OWNER_NAME).read_text().split()
            dead = owner_host == host and not _alive(int(pid))
        except (OSError, ValueError):
            continue
        if dead:
            shutil.rmtree(staging, ignore_errors=True)
            logger.info("removed %s, left by a run that died (pid %s)", staging, pid)
            removed.append(staging)
    return removed


def _check_final(final: Path, replace: bool) -> str | None:
    """Why ``final`` cannot become an output folder, or None if it can.

    ``replace``: a previous shoulder-fem result in ``final`` may be replaced.
    """
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
        if any(final.iterdir()) and not is_result(final):
            return (
                f"is a non-empty folder without {' or '.join(RESULT_FILES)} (not a "
                "shoulder-fem result); refusing to replace it"
            )
        if is_result(final) and not replace:
            held = next(name for name in RESULT_FILES if (final / name).is_file())
            return f"holds a previous result ({held}); give --force to replace it"
    return None


#: The file at the top of every result folder: a run's summary, a bench's report or state (a
#: stopped bench), compare's report, a mesh's statistics. A folder holding one may be replaced
#: by a new result.
RESULT_FILES = (SUMMARY_NAME, "report.json", "bench.json", "comparison.json", "mesh.json")


def is_result(folder: Path) -> bool:
    """Whether ``folder`` is a shoulder-fem result (run, bench, compare or mesh)."""
    return any((folder / name).is_file() for name in RESULT_FILES)


class OutputDir:
    """An output folder that appears complete or not at all.

    Construction (collective) validates ``final``, removes the staging folders of ``final``
    left by runs that died (:func:`remove_stale_partials`) and creates the staging folder
    ``<final>.partial-<token>`` with a ``scratch`` folder and its owner inside; the run writes into
    :attr:`path`. :meth:`commit` renames the staging folder to ``final``, replacing a previous
    shoulder-fem result there (a folder holding one of :data:`RESULT_FILES`) if ``replace``;
    :meth:`abort` removes it.

    As a context manager it commits on normal exit and aborts on an exception, unless the caller
    has already committed (e.g. to keep the steps before a diverged solve readable before
    re-raising). Either way no ``.partial-*`` folder is left behind.

    Args:
        final: the folder the results should end up in (``--out``).
        comm: the run's communicator.
        replace: a previous shoulder-fem result in ``final`` may be replaced (``--force``).

    Raises:
        OutputError: on every rank, if the parent of ``final`` does not exist or is not writable,
            or ``final`` exists and is neither empty nor a previous shoulder-fem result, or is
            one and ``replace`` is False.
    """

    def __init__(self, final: Path, comm: MPI.Comm, replace: bool = False) -> None:
        self.comm = comm
        self.final = Path(final).expanduser().absolute()
        self.replace = replace
        reply: tuple[str | None, str | None] = (None, None)
        if comm.rank == 0:
            reason = _check_final(self.final, replace)
            if reason is not None:
                reply = (None, f"--out {self.final}: {reason}")
            else:
                remove_stale_partials(self.final)
                token = secrets.token_hex(4)
                staging = self.final.parent / f"{self.final.name}.partial-{token}"
                # made under a hidden name and renamed once its owner is written, so that a
                # visible staging folder always names its owner (a run killed between the
                # owner file's creation and its write left an empty one, never removed)
                hidden = self.final.parent / f".{staging.name}"
                try:
                    hidden.mkdir()
                    (hidden / "scratch").mkdir()
                    (hidden / OWNER_NAME).write_text(f"{socket.gethostname()} {os.getpid()}\n")
                    hidden.rename(staging)
                    reply = (token, None)
                except OSError as exc:
                    shutil.rmtree(hidden, ignore_errors=True)
                    reply = (None, f"--out {self.final}: cannot create {staging}: {exc.strerror}")
        token, error = comm.bcast(reply, root=0)
        if error is not None:
            raise OutputError(error)
        self.token: str = token
        self._staging = self.final.parent / f"{self.final.name}.partial-{token}"
        self._state = "open"
        _OPEN.add(self)
        _open_changed()

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
            _closed(self)
            raise OutputError(error)
        self._state = "committed"
        _closed(self)
        return self.final

    def _commit_rank0(self) -> None:
        shutil.rmtree(self.scratch, ignore_errors=True)
        with contextlib.suppress(FileNotFoundError):
            (self._staging / OWNER_NAME).unlink()
        final = self.final
        trash = None
        if final.is_symlink() or final.exists():
            if final.is_symlink() or not final.is_dir():
                raise OutputError("the output path became a file or link during the run")
            if not any(final.iterdir()):
                final.rmdir()
            elif is_result(final) and not self.replace:
                raise OutputError("another result was written there during the run")
            elif is_result(final):
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
        _closed(self)
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
