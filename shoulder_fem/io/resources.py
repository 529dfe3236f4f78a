"""CPU, memory and disk accounting of a run, reduced over MPI ranks.

What a run costs is part of its result (ARCHITECTURE, "Interfaces"): every ``summary.json`` holds

* ``wall_s``: elapsed time [s], the maximum over ranks;
* ``cpu_s``: user + system CPU time of the processes [s], summed over ranks;
* ``peak_rss_mb``: each rank's peak resident memory, summed over ranks [MB], and
  ``peak_rss_rank_max_mb`` the largest of them;
* ``temp_disk_mb``: the peak size of the run's scratch folder [MB];
* ``results_disk_mb``: the size of the output folder at the end [MB];

and the same wall / CPU / memory figures for named stages of the run. Throughout this module
1 MB = 2**20 bytes (the unit of ``/proc/self/status``' kB is also 1024 bytes).

The BLAS actually loaded in the process is read from ``/proc/self/maps`` by :func:`blas_library`.
"""

from __future__ import annotations

import contextlib
import ctypes
import glob
import os
import re
import resource
import sys
import time
import weakref
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from mpi4py import MPI

__all__ = [
    "MB",
    "ResourceMonitor",
    "blas_library",
    "dir_size_bytes",
    "thread_settings",
]

MB = 2**20
"""Bytes in one MB as used in every ``*_mb`` figure (MiB)."""

_STATUS = Path("/proc/self/status")
_CLEAR_REFS = Path("/proc/self/clear_refs")
_MAPS = Path("/proc/self/maps")

_LIVE_MONITORS: weakref.WeakSet[ResourceMonitor] = weakref.WeakSet()
"""Every monitor in this process: all must see the high-water mark before anyone resets it."""


def dir_size_bytes(
    path: str | os.PathLike[str], exclude: str | os.PathLike[str] | None = None
) -> int:
    """Total size of all regular files below a folder.

    Symbolic links are not followed; files that vanish during the walk are skipped, so this is
    safe to call while other processes write into the folder. Not collective.

    Args:
        path: folder (or single file) to measure. A missing path has size 0.
        exclude: a folder below ``path`` whose contents are not counted (e.g. the scratch folder
            inside an output folder).

    Returns:
        Sum of the files' sizes [bytes] (apparent size, ``st_size``).
    """
    root = Path(path)
    skip = os.path.abspath(exclude) if exclude is not None else None
    try:
        st = root.lstat()
    except FileNotFoundError:
        return 0
    if not root.is_dir() or root.is_symlink():
        return st.st_size if root.is_file() else 0
    total = 0
    stack = [os.fspath(root)]
    while stack:
        folder = stack.pop()
        if skip is not None and os.path.abspath(folder) == skip:
            continue
        try:
            with os.scandir(folder) as entries:
                for entry in entries:
                    try:
                        if entry.is_dir(follow_symlinks=False):
                            stack.append(entry.path)
                        elif entry.is_file(follow_symlinks=False):
                            total += entry.stat(follow_symlinks=False).st_size
                    except FileNotFoundError:
                        continue
        except (FileNotFoundError, NotADirectoryError):
            continue
    return total


def _cpu_seconds() -> float:
    """User + system CPU time of this process, all threads, children excluded [s]."""
    t = os.times()
    return t.user + t.system


def _memory_kib() -> tuple[int, int]:
    """This process' resident-memory high-water mark and current resident memory [KiB].

    Reads ``VmHWM`` and ``VmRSS`` from ``/proc/self/status``; where that is unavailable, both are
    the process peak ``ru_maxrss`` (KiB on Linux).
    """
    try:
        text = _STATUS.read_text()
        hwm = re.search(r"^VmHWM:\s+(\d+)\s*kB", text, re.MULTILINE)
        rss = re.search(r"^VmRSS:\s+(\d+)\s*kB", text, re.MULTILINE)
        if hwm is not None and rss is not None:
            return int(hwm.group(1)), int(rss.group(1))
    except OSError:
        pass
    peak = int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
    return peak, peak


def _reset_hwm() -> bool:
    """Reset the kernel's resident-memory high-water mark of this process.

    Returns:
        True if the reset was accepted and took effect (afterwards ``VmHWM`` is close to
        ``VmRSS``), False if the kernel or the sandbox refused it.
    """
    try:
        with open(_CLEAR_REFS, "w") as f:
            f.write("5")
    except OSError:
        return False
    hwm, rss = _memory_kib()
    # After a reset VmHWM restarts from VmRSS; allow for memory touched or freed meanwhile.
    return hwm - rss <= 4 * 1024


def release_memory() -> int:
    """Collect garbage and return the heap's free pages to the kernel (glibc ``malloc_trim``).

    Returns:
        The resident memory afterwards (KiB, ``VmRSS``).
    """
    import gc

    gc.collect()
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    return _memory_kib()[1]


@dataclass
class _OpenStage:
    name: str
    wall0: float
    cpu0: float
    peak_kib: int


class ResourceMonitor:
    """Measures wall time, CPU time, peak memory and disk use of a run and of its stages.

    Construct it at the start of the run, on every rank. :meth:`stage` and :meth:`sample` use no
    MPI communication; :meth:`finish` is collective and does all reductions. Every rank must open
    the same stages in the same order.

    Peak memory of a stage: at stage start the kernel's resident-memory high-water mark
    (``VmHWM``) is reset by writing ``5`` to ``/proc/self/clear_refs`` (Linux >= 4.0, own
    process). If the kernel refuses, the stage reports the process peak up to the stage end
    instead, and the output says so with ``peak_rss_stage_reset = false``. The run-wide peak is
    the peak since the monitor was made: at construction the freed heap is given back to the
    kernel (``malloc_trim``) and the mark is reset, so that of two runs in one process
    (``bench``) the second does not report the first's peak; the resident memory left at that
    point is reported as ``start_rss_mb``. The high-water mark is read before every reset and
    kept by every monitor alive in the process.

    Example:
        >>> mon = ResourceMonitor(comm, scratch_dir=out.scratch)
        >>> with mon.stage("part1-rigid"):
        ...     for step in steps:
        ...         solve(step)
        ...         mon.sample()
        >>> resources = mon.finish(out.path)
        >>> stages = mon.stages

    Args:
        comm: the run's communicator.
        scratch_dir: the run's temporary folder, shared by all ranks (it is measured on rank 0
            only); None if the run has none.
    """

    def __init__(self, comm: MPI.Comm, scratch_dir: Path | None = None) -> None:
        self.comm = comm
        self.scratch_dir = Path(scratch_dir) if scratch_dir is not None else None
        # A run measures its own peak, not that of what ran before it in the process (bench runs
        # both methods in one): give freed memory back to the kernel and restart the mark.
        for monitor in list(_LIVE_MONITORS):
            monitor._fold_peak()
        self.start_rss_kib = release_memory()
        self._reset_ok = _reset_hwm()
        self._wall0 = time.perf_counter()
        self._cpu0 = _cpu_seconds()
        self._run_peak_kib = _memory_kib()[0]
        self._open: list[_OpenStage] = []
        self._local_stages: list[dict[str, Any]] = []
        self._scratch_peak = 0
        self._stages: list[dict[str, Any]] | None = None
        _LIVE_MONITORS.add(self)
        self.sample()

    def _fold_peak(self) -> None:
        """Fold the current high-water mark into the run peak and every open stage's peak."""
        hwm = _memory_kib()[0]
        self._run_peak_kib = max(self._run_peak_kib, hwm)
        for st in self._open:
            st.peak_kib = max(st.peak_kib, hwm)

    @contextlib.contextmanager
    def stage(self, name: str) -> Iterator[None]:
        """Measure the enclosed block as a named stage (not collective; stages may nest).

        Records the stage's wall time [s], CPU time [s] and peak resident memory [KiB, reported
        in MB by :attr:`stages`]. The stage is recorded even if the block raises.

        Args:
            name: stage name, e.g. ``"part1-rigid"``.
        """
        for monitor in list(_LIVE_MONITORS):
            monitor._fold_peak()
        reset = _reset_hwm()
        self._reset_ok = self._reset_ok and reset
        start_hwm = _memory_kib()[0]
        st = _OpenStage(name, time.perf_counter(), _cpu_seconds(), start_hwm)
        self._open.append(st)
        try:
            yield
        finally:
            self._fold_peak()
            self._open.remove(st)
            self._local_stages.append(
                {
                    "name": name,
                    "wall_s": time.perf_counter() - st.wall0,
                    "cpu_s": _cpu_seconds() - st.cpu0,
                    "peak_kib": st.peak_kib,
                }
            )
            self.sample()

    def sample(self) -> None:
        """Record the scratch folder's current size to track its peak (cheap, not collective).

        Call it whenever temporary files may be at their largest, e.g. once per time step. Only
        rank 0 measures (the scratch folder is shared); other ranks return at once.
        """
        if self.scratch_dir is None or self.comm.rank != 0:
            return
        self._scratch_peak = max(self._scratch_peak, dir_size_bytes(self.scratch_dir))

    def finish(self, results_dir: Path) -> dict[str, Any]:
        """Reduce the whole run's figures over ranks (collective).

        Args:
            results_dir: the output folder whose size is reported as ``results_disk_mb``; the
                scratch folder is excluded if it lies inside.

        Returns:
            ``{"wall_s", "cpu_s", "peak_rss_mb", "start_rss_mb", "temp_disk_mb",
            "results_disk_mb", "ranks", "peak_rss_stage_reset"}``, the same on every rank: wall
            time since construction [s] (max over ranks), CPU time since construction [s] (sum
            over ranks), each rank's peak resident memory since construction summed over ranks
            [MB], the resident memory at construction (after freed memory was given back; what
            the process held before the run, e.g. the interpreter and libraries, or the heap left
            by an earlier run in the same process) summed over ranks [MB], the peak
            scratch-folder size seen [MB],
            the size of ``results_dir`` now [MB], the number of ranks, and whether the per-stage
            memory peaks are true per-stage peaks (True) or process peaks up to each stage's end
            (False). The per-stage figures are then available from :attr:`stages`.
        """
        from mpi4py import MPI

        comm = self.comm
        self._fold_peak()
        self.sample()
        wall = time.perf_counter() - self._wall0
        cpu = _cpu_seconds() - self._cpu0

        names = [s["name"] for s in self._local_stages]
        all_names = comm.allgather(names)
        if any(n != all_names[0] for n in all_names):
            raise RuntimeError(
                f"ResourceMonitor: ranks recorded different stages: {all_names}; "
                "every rank must open the same stages in the same order"
            )
        n = len(names)
        walls = [s["wall_s"] for s in self._local_stages]
        mx = np.array([wall, *walls, self._run_peak_kib / 1024.0], dtype=np.float64)
        sm = np.array(
            [cpu, self._run_peak_kib / 1024.0, float(self._reset_ok), self.start_rss_kib / 1024.0]
            + [s["cpu_s"] for s in self._local_stages]
            + [s["peak_kib"] / 1024.0 for s in self._local_stages],
            dtype=np.float64,
        )
        mx_all = np.empty_like(mx)
        sm_all = np.empty_like(sm)
        comm.Allreduce(mx, mx_all, op=MPI.MAX)
        comm.Allreduce(sm, sm_all, op=MPI.SUM)

        disk = None
        if comm.rank == 0:
            exclude = None
            if self.scratch_dir is not None:
                results_abs = os.path.abspath(results_dir)
                scratch_abs = os.path.abspath(self.scratch_dir)
                if os.path.commonpath([results_abs, scratch_abs]) == results_abs:
                    exclude = scratch_abs
            disk = (self._scratch_peak, dir_size_bytes(results_dir, exclude=exclude))
        temp_bytes, results_bytes = comm.bcast(disk, root=0)

        self._stages = [
            {
                "name": names[i],
                "wall_s": float(mx_all[1 + i]),
                "cpu_s": float(sm_all[4 + i]),
                "peak_rss_mb": float(sm_all[4 + n + i]),
            }
            for i in range(n)
        ]
        return {
            "wall_s": float(mx_all[0]),
            "cpu_s": float(sm_all[0]),
            "peak_rss_mb": float(sm_all[1]),
            "peak_rss_rank_max_mb": float(mx_all[-1]),
            "start_rss_mb": float(sm_all[3]),
            "temp_disk_mb": temp_bytes / MB,
            "results_disk_mb": results_bytes / MB,
            "ranks": comm.size,
            "peak_rss_stage_reset": bool(sm_all[2] == comm.size),
        }

    @property
    def stages(self) -> list[dict[str, Any]]:
        """Per-stage figures reduced over ranks, in order of completion.

        Each is ``{"name", "wall_s", "cpu_s", "peak_rss_mb"}``: wall time [s] (max over ranks),
        CPU time [s] (sum over ranks), peak resident memory during the stage [MB] (sum over ranks;
        see ``peak_rss_stage_reset`` in :meth:`finish`). Available after :meth:`finish`.
        """
        if self._stages is None:
            raise RuntimeError("ResourceMonitor.stages is available after finish()")
        return self._stages


def _describe_blas(path: str) -> str:
    """Human name of the BLAS implementation behind a shared-library path."""
    p = path.lower()
    variant = re.search(r"/(?:openblas|blis)-(\w+)/", p)
    suffix = f" ({variant.group(1)})" if variant else ""
    if "openblas" in p:
        bundled = " (bundled)" if re.search(r"\.libs/|site-packages/", p) else ""
        return f"OpenBLAS{suffix}{bundled}"
    if "mkl" in p:
        return "Intel MKL"
    if "blis" in p:
        return f"BLIS{suffix}"
    if "flexiblas" in p:
        return "FlexiBLAS"
    if "atlas" in p:
        return "ATLAS"
    if "/blas/" in p:
        return "reference BLAS (netlib)"
    return "BLAS"


_BLAS_NAME = re.compile(
    r"^lib(?:openblas\w*|blas|cblas|mkl_rt|mkl_core|blis\w*|flexiblas|[st]atlas)[.\-_]", re.I
)


def _map_petsc_library() -> None:
    """Map PETSc's shared libraries (and so its BLAS) into the process without initialising PETSc.

    Importing ``petsc4py.PETSc`` would call ``PetscInitialize``, whose counterpart at exit is
    collective: doing it on one rank only hangs the run at exit. ``dlopen`` of the extension
    module maps the same libraries with no MPI involved.
    """
    if "petsc4py.PETSc" in sys.modules:
        return
    try:
        from petsc4py import lib

        path, arch = lib.getPathArchPETSc()
        for so in glob.glob(os.path.join(path, arch, "PETSc*.so")):
            ctypes.CDLL(so, mode=ctypes.RTLD_LOCAL)
    except (ImportError, OSError, AttributeError, ValueError):
        pass


def blas_library() -> str:
    """The BLAS library actually loaded in this process (not collective).

    numpy and PETSc's libraries are loaded first (PETSc without initialising it, so this is safe
    on one rank) so that their BLAS is mapped; then ``/proc/self/maps`` is searched for BLAS
    shared libraries and their paths resolved. The library behind the ``libblas`` interface
    (what numpy and PETSc link on Debian) is reported first; other BLAS families mapped at the
    same time are appended.

    Returns:
        E.g. ``"OpenBLAS (openmp) /usr/lib/x86_64-linux-gnu/openblas-openmp/libblas.so.3"``, or
        ``"unknown (...)"`` where the memory maps cannot be read.
    """
    import numpy  # noqa: F401

    _map_petsc_library()
    try:
        lines = _MAPS.read_text().splitlines()
    except OSError:
        return "unknown (no /proc/self/maps)"
    paths: list[str] = []
    for line in lines:
        fields = line.split(maxsplit=5)
        if len(fields) < 6 or not fields[5].startswith("/"):
            continue
        real = os.path.realpath(fields[5].strip())
        if _BLAS_NAME.match(os.path.basename(real)) and real not in paths:
            paths.append(real)
    if not paths:
        return "unknown (no BLAS library mapped)"
    paths.sort(key=lambda q: not os.path.basename(q).startswith("libblas."))
    main = paths[0]
    text = f"{_describe_blas(main)} {main}"
    seen = {_describe_blas(main)}
    for q in paths[1:]:
        kind = _describe_blas(q)
        if kind not in seen:
            seen.add(kind)
            text += f"; also mapped: {kind} {q}"
    return text


def thread_settings() -> dict[str, str | None]:
    """The thread-count environment of this process (None where unset).

    Returns:
        ``{"OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"}`` as strings.
    """
    keys = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
    return {k: os.environ.get(k) for k in keys}
