"""The ``shoulder-fem`` entry point: parser, logging, dispatch, exit statuses.

``main(argv) -> int``; heavy imports (dolfinx, PETSc) happen inside the commands so that
``--help`` is instant. Under ``mpirun -n N`` every command behaves the same and writes its
output once. Errors in the input print one line naming what is wrong and exit with status 2;
a diverged solve exits with status 3 after writing the completed steps. SIGTERM (``kill``, a
batch system's time limit) unwinds the run like an error: the unfinished output folder is
removed, and the command exits with status 143.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import logging
import os
import signal
import sys
import time
from collections.abc import Callable
from pathlib import Path

from shoulder_fem import __version__
from shoulder_fem.cli.args import add_out_arguments, add_run_arguments
from shoulder_fem.cli.commands import EXIT_INPUT, EXIT_SOLVER
from shoulder_fem.cli.mesh import add_mesh_parser

logger = logging.getLogger("shoulder_fem")

EXIT_INTERRUPTED = 128 + signal.SIGINT  # 130, the shell's status for Ctrl-C
EXIT_TERMINATED = 128 + signal.SIGTERM  # 143, the shell's status for a process ended by SIGTERM
EXIT_ABORTED = 70  # an unexpected error on one rank of several: the job is aborted


class _Terminated(SystemExit):
    """Raised by the SIGTERM handler.

    Not an ``Exception``: no ``except Exception`` stops it on its way out, and every ``with``
    block (the output folders) unwinds.
    """


def _raise_on_sigterm(signum, frame) -> None:
    raise _Terminated(EXIT_TERMINATED)


def _watch_sigterm_under_mpi(started: float, args) -> Callable[[], None]:
    """Under MPI, rank 0 alone acts on SIGTERM, at once; the other ranks ignore it.

    mpirun forwards SIGTERM to every rank, then kills them after ``odls_base_sigkill_timeout``
    seconds. With the serial runs' handler (an exception that unwinds the run), a rank that
    raised left the others blocked in an MPI collective and rank 0, the one that removes the
    unfinished output folder, was killed with the folder half-written. Now the other ranks
    carry on until they are killed, so rank 0's collectives complete, and rank 0's clean-up
    is done by its stop guard (``stop_guard.py``), a process that learns of the signal at once
    even while rank 0's main thread is inside a long C call (where Python cannot run a
    handler): it removes the unfinished output folders and the unfinished form-cache claims and
    says so in one line. Rank 0's handler then ends the process with status 143 (no unwinding:
    the code on the way out could call a collective the other ranks never join); without a
    guard it does the clean-up itself. Serial runs keep the orderly path.

    Returns:
        What ends the watch when the command is over (the guard's process, its watcher).
    """
    from mpi4py import MPI

    comm = MPI.COMM_WORLD
    if comm.size == 1:
        return lambda: None
    if comm.rank != 0:
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        return lambda: None
    from shoulder_fem.cli.stop_guard import StopGuard
    from shoulder_fem.io.output import abort_open_outputs, watch_open_outputs

    guard = None
    try:
        guard = StopGuard(f"stopped by SIGTERM{_what_was_kept(args)}", _form_cache(), started)
    except OSError as err:  # no process or pipe to be had: rank 0 cleans up itself
        logger.debug("no stop guard (%s): rank 0's handler removes the output", err)

    def stop(signum, frame) -> None:
        if guard is None or not guard.wait_done():
            abort_open_outputs()
            _say_stopped("stopped by SIGTERM", started, args)
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(EXIT_TERMINATED)

    signal.signal(signal.SIGTERM, stop)
    if guard is None:
        return lambda: None
    unwatch = watch_open_outputs(lambda folders: guard.update(remove=folders))

    def end() -> None:
        unwatch()
        guard.close()

    return end


class _PipeSafe:
    """A text stream whose reader may go away (``shoulder-fem run ... | head``).

    Once a write or flush meets a broken pipe, its file descriptor is pointed at /dev/null, so
    the rest of the output (Python's, and the libraries' own C writes) is dropped and the run
    goes on to write its results, instead of stopping half-written.
    """

    def __init__(self, stream) -> None:
        self.stream = stream

    def write(self, text: str) -> int:
        try:
            return self.stream.write(text)
        except BrokenPipeError:
            self._to_devnull()
            return len(text)

    def flush(self) -> None:
        try:
            self.stream.flush()
        except BrokenPipeError:
            self._to_devnull()

    def _to_devnull(self) -> None:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, self.stream.fileno())
        os.close(devnull)
        with contextlib.suppress(BrokenPipeError):  # what the buffer held goes there too
            self.stream.flush()

    def __getattr__(self, name: str):
        return getattr(self.stream, name)


def _survive_broken_pipes() -> Callable[[], None]:
    """Make stdout and stderr :class:`_PipeSafe`; returns the function that restores them.

    PETSc's initialization installs a SIGPIPE handler that aborts the process (exit status 59,
    PETSC_ERR_SIG) and leaves the unfinished output folder behind: SIGPIPE is given back to
    Python's own setting, ignored, so that a write to a closed pipe is a ``BrokenPipeError``.
    """
    from petsc4py import PETSc  # noqa: F401  initialized now, so its handler is set now

    signal.signal(signal.SIGPIPE, signal.SIG_IGN)
    saved = sys.stdout, sys.stderr
    sys.stdout, sys.stderr = _PipeSafe(sys.stdout), _PipeSafe(sys.stderr)

    def restore() -> None:
        sys.stdout, sys.stderr = saved

    return restore


class _RankFilter(logging.Filter):
    def __init__(self, rank: int, all_ranks: bool):
        super().__init__()
        self.rank, self.all_ranks = rank, all_ranks

    def filter(self, record: logging.LogRecord) -> bool:
        record.rank_prefix = f"CPU {self.rank}: " if self.all_ranks else ""
        return self.all_ranks or self.rank == 0


_DISTUTILS = frozenset({"distutils", "_distutils"})  # the stdlib's, or setuptools' copy


class _FormCompilerFilter(logging.Filter):
    """Keeps the form compiler's build steps out of the log, but one line per module at -vv.

    dolfinx compiles each form through FFCx and cffi; cffi runs distutils' ``build_ext``, which
    logs four lines per compiled module at INFO through the root logger ("running build_ext",
    "building '<module>' extension", the compiler and linker command lines), after lowering the
    root logger's level to INFO for the build. This filter drops them, except the "building"
    line when ``debug``.
    """

    def __init__(self, debug: bool) -> None:
        super().__init__()
        self.debug = debug

    def filter(self, record: logging.LogRecord) -> bool:
        if record.name != "root" or record.levelno >= logging.WARNING:
            return True
        if not _DISTUTILS & set(Path(record.pathname).parts):
            return True
        return self.debug and record.getMessage().startswith("building '")


def setup_logging(verbosity: int, all_ranks: bool) -> None:
    """Configure the package logger once: rank 0 only unless ``all_ranks``.

    Other libraries log through the root logger: warnings and errors only, unless ``verbosity``
    is 2 or more (``-vv``: debug). The form compiler's build steps are quiet below ``-vv`` and one
    line per compiled module at ``-vv`` (:class:`_FormCompilerFilter`).
    """
    from mpi4py import MPI

    debug = verbosity > 1
    root = logging.getLogger()
    # Claim the root logger first (as logging.basicConfig would), so a library's later
    # logging.basicConfig is a no-op. The level is on the handler too: distutils changes the
    # root logger's level around each form compilation, not the handler's.
    if not root.handlers:
        level = logging.DEBUG if debug else logging.WARNING
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(logging.Formatter(logging.BASIC_FORMAT))
        handler.setLevel(level)
        handler.addFilter(_FormCompilerFilter(debug))
        root.addHandler(handler)
        root.setLevel(level)
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
    parser.add_argument("--version", action="version", version=f"shoulder-fem {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("scenes", help="list the built-in scenes, or one scene's parameters")
    p.add_argument("name", nargs="?", help="a scene (name or .toml path): list its parameters")

    p = sub.add_parser("run", help="run one scene with one method")
    p.add_argument("scene", help="built-in scene name or path to a .toml scene file")
    p.add_argument("--method", required=True, choices=["coupled", "decoupled"])
    add_run_arguments(p)

    p = sub.add_parser("compare", help="compare two runs (reference first)")
    p.add_argument("ref", type=Path, help="output folder of the reference run (coupled)")
    p.add_argument("other", type=Path, help="output folder of the other run (decoupled)")
    add_out_arguments(p, "folder for metrics and figures")

    p = sub.add_parser("bench", help="run both methods and write the comparison report")
    p.add_argument("scene", help="built-in scene name or path to a .toml scene file")
    add_run_arguments(p)
    p.add_argument(
        "--resume",
        action="store_true",
        help="reuse the methods a stopped bench into --out finished (same scene, level, "
        "parameters, solver, ranks and code)",
    )

    p = sub.add_parser(
        "sweep",
        help="part 2 again for each value of the scapula's material from one decoupled run's "
        "part 1",
    )
    p.add_argument("scene", help="built-in scene name or path to a .toml scene file")
    p.add_argument(
        "--from",
        dest="source",
        type=Path,
        required=True,
        help="a finished decoupled run's output folder (its part 1 is reused)",
    )
    _add_values_arguments(
        p,
        "sweep",
        "a swept key and its values (repeatable: every combination); only keys part 1 does "
        "not depend on, e.g. scapula_modulus_factor=0.5,1,2",
    )

    p = sub.add_parser(
        "study",
        help="one whole run per combination of values of any keys (the soft tissues' "
        "constants, the implant): cost and outputs of every variant",
    )
    p.add_argument("scene", help="built-in scene name or path to a .toml scene file")
    p.add_argument("--method", choices=["coupled", "decoupled"], default="decoupled")
    p.add_argument("--level", default=None, help="mesh level (default: the scene's)")
    _add_values_arguments(
        p,
        "study",
        "a studied key and its values, each with its unit or in SI (repeatable: every "
        "combination), e.g. muscle_alpha=0.06MPa,0.12MPa,0.24MPa",
    )

    add_mesh_parser(sub)
    return parser


def _add_values_arguments(p, command: str, help_set: str) -> None:
    """``--set KEY=V1,V2,...`` (repeatable) and ``--out`` of a sweep or a study."""
    p.add_argument(
        "--set",
        dest="sets",
        action="append",
        default=[],
        metavar="KEY=V1,V2,...",
        help=help_set,
    )
    p.add_argument("--out", type=Path, required=True, help=f"a new folder for the {command}")


def pin_threads() -> None:
    """One BLAS/OpenMP thread per MPI rank, unless the user set it (before numpy loads).

    OpenBLAS/OpenMP threads on top of MPI ranks slow MUMPS down here; OpenBLAS reads these
    variables when it loads, so entry points call this first.
    """
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ.setdefault(var, "1")


def _form_cache() -> Path | None:
    """The form cache's folder (dolfinx's JIT parameters), None without dolfinx."""
    try:
        import dolfinx.jit
    except ImportError:
        return None
    return Path(dolfinx.jit.get_parameters()["cache_dir"])


def remove_unfinished_forms(since: float) -> list[Path]:
    """Remove the form-cache claims this stopped process left unfinished (since ``since``).

    See :func:`shoulder_fem.cli.stop_guard.remove_unfinished_forms`.
    """
    from shoulder_fem.cli.stop_guard import remove_unfinished_forms as remove

    cache = _form_cache()
    return [] if cache is None else remove(cache, since)


def _say_stopped(how: str, started: float, args) -> None:
    """A stopped command's clean-up of the form cache and its one line (what became of --out)."""
    from shoulder_fem.cli import commands

    remove_unfinished_forms(started)
    commands.error(f"{how}{_what_was_kept(args)}")


def _what_was_kept(args) -> str:
    """The end of the message of a stopped command: what happened to its output."""
    out = getattr(args, "out", None)
    kept = getattr(args, "kept", None)
    if out and kept:
        return (
            f": the finished {' and '.join(kept)} run kept in {out} "
            "(bench --resume continues from it)"
        )
    return f": the unfinished output {out} was removed" if out else ""


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit status."""
    started = time.time()
    pin_threads()
    args = build_parser().parse_args(argv)
    verbosity = 0 if args.quiet else args.verbose
    restore_streams = _survive_broken_pipes()
    try:
        return _main(args, started, verbosity)
    finally:
        restore_streams()


def _main(args, started: float, verbosity: int) -> int:
    setup_logging(verbosity, args.log_all_ranks)
    import matplotlib

    matplotlib.use("Agg")  # figures are files; no display needed
    from shoulder_fem.cli import commands
    from shoulder_fem.cli.bench import cmd_bench
    from shoulder_fem.cli.mesh import cmd_mesh
    from shoulder_fem.io.output import OutputError
    from shoulder_fem.scene import SceneError

    signal.signal(signal.SIGTERM, _raise_on_sigterm)
    end_watch = _watch_sigterm_under_mpi(started, args)
    # Ctrl-C raises KeyboardInterrupt (one line, exit 130, the unfinished output removed). The
    # gmsh 4.8 module sets SIGINT to its default action when imported (a Ctrl-C while meshing
    # killed the run with no clean-up, measured): import it first, then take SIGINT back.
    with contextlib.suppress(ImportError):
        import gmsh  # noqa: F401
    signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        return {
            "scenes": commands.cmd_scenes,
            "run": commands.cmd_run,
            "compare": commands.cmd_compare,
            "bench": cmd_bench,
            "sweep": commands.cmd_sweep,
            "study": commands.cmd_study,
            "mesh": cmd_mesh,
        }[args.command](args)
    except (SceneError, OutputError, commands.InputFailure) as err:
        commands.error(str(err))
        from shoulder_fem.io.fields import hdf5_failed

        if hdf5_failed():  # HDF5's teardown would crash the process: end it now
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(EXIT_INPUT)
        return EXIT_INPUT
    except OSError as err:  # a full disk outside the fields (summary, arrays)
        if err.errno not in (errno.ENOSPC, errno.EDQUOT):
            raise
        commands.error(f"{err.filename or 'a file'}: {err.strerror}: is the disk full?")
        return EXIT_INPUT
    except commands.SolverFailure as err:
        commands.error(str(err))
        return EXIT_SOLVER
    except _Terminated:
        _say_stopped("stopped by SIGTERM", started, args)
        return EXIT_TERMINATED
    except KeyboardInterrupt:
        _say_stopped("interrupted (Ctrl-C)", started, args)
        return EXIT_INTERRUPTED
    except Exception:
        _abort_other_ranks()
        raise
    finally:
        end_watch()


def _abort_other_ranks() -> None:
    """Under MPI, an unexpected error on one rank: its traceback, then MPI_Abort.

    The other ranks would wait in their next collective for this one until the job's time
    limit (on a cluster: hours of allocation, no message). The rank says which it is; a run's
    unfinished output folder is removed by the next run into the same ``--out``.
    """
    from mpi4py import MPI

    comm = MPI.COMM_WORLD
    if comm.size == 1:
        return
    import traceback

    sys.stderr.write(
        f"shoulder-fem: error on rank {comm.rank} of {comm.size}, aborting the job:\n"
        + traceback.format_exc()
    )
    sys.stderr.flush()
    comm.Abort(EXIT_ABORTED)
