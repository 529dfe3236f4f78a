"""Fields for ParaView: time series of dolfinx functions in one XDMF/HDF5 file pair.

A run writes them to ``<out>/fields/<name>.xdmf`` (:meth:`OutputDir.field_file
<shoulder_fem.io.output.OutputDir.field_file>`) through :class:`FieldWriter`.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import dolfinx.fem
    import dolfinx.mesh
    from mpi4py import MPI

__all__ = ["FieldWriter"]

_HDF5_QUIET = []


def _quiet_hdf5() -> None:
    """Turn off HDF5's own error printing (once per process).

    A failed write (a full disk) printed HDF5's whole error stack, about 70 lines per rank,
    before dolfinx raised; the error is reported in one line instead (:class:`FieldWriter`).
    The library is the one dolfinx loaded (found in the process's memory map).
    """
    if _HDF5_QUIET:
        return
    _HDF5_QUIET.append(True)
    import ctypes
    import re

    try:
        maps = Path("/proc/self/maps").read_text()
    except OSError:
        return
    for lib in sorted(set(re.findall(r"(/\S*libhdf5[^/\s]*\.so[^/\s]*)", maps))):
        if "_hl" in Path(lib).name:
            continue
        try:
            ctypes.CDLL(lib).H5Eset_auto2(ctypes.c_int64(0), None, None)  # H5E_DEFAULT
        except (OSError, AttributeError):
            continue


_HDF5_FAILED = []


def hdf5_failed() -> bool:
    """Whether a field file failed to write or close in this process.

    HDF5 is then in a state where the file's destructor at the interpreter's exit crashed the
    process (a segmentation fault after the one-line error, measured on a full disk): the
    command line ends such a process at once instead (``os._exit``).
    """
    return bool(_HDF5_FAILED)


def _write_failed(path: Path, what: str, err: Exception) -> Exception:
    """The one-line error of a write that failed (with the free space of its file system)."""
    import re
    import shutil

    from shoulder_fem.io.output import OutputError

    _HDF5_FAILED.append(True)
    try:
        free = f"{shutil.disk_usage(path.parent).free / 1e6:.1f} MB free there"
    except OSError:
        free = "free space unknown"
    shown = re.sub(r"\.partial-[0-9a-f]+", "", str(path))  # the output's own name
    reason = str(err).strip().rstrip(".")
    return OutputError(f"{shown}: {what} failed ({reason}; {free}): is the disk full?")


def _lagrange_degree(u: dolfinx.fem.Function) -> int:
    """The degree of a (vector, tensor) Lagrange function; 0 for any other element."""
    element = u.function_space.ufl_element()
    sub = element.sub_elements()[0] if element.num_sub_elements() else element
    return element.degree() if sub.family() in ("Lagrange", "Q") else 0


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

    A Lagrange function of degree 2 or more is also written whole, at all its nodes, to
    ``<stem>_<name>.pvd`` (VTK's higher-order Lagrange cells, dolfinx's ``VTKFile``; ParaView
    opens it, meshio 5 does not read its VTK XML 2.2): the XDMF file shows it at the vertices
    only.

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
        _quiet_hdf5()
        self._closed = True
        try:
            self._file = XDMFFile(comm, str(self.path), "w")
            self._file.write_mesh(mesh)
        except RuntimeError as err:
            raise _write_failed(self.path, "writing the mesh", err) from None
        self._times: dict[str, list[float]] = {}
        #: The higher-order functions' VTK series, per function name.
        self._vtk: dict[str, object] = {}
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
            try:
                self._file.write_function(u, t)
            except RuntimeError as err:
                raise _write_failed(self.path, f"writing {u.name!r} at {t:g}", err) from None
            if _lagrange_degree(u) > 1:
                self._write_whole(u, t)
            self._times.setdefault(u.name, []).append(t)

    def _write_whole(self, u: dolfinx.fem.Function, t: float) -> None:
        """Append a higher-order Lagrange function at all its nodes to its VTK series."""
        from dolfinx.io import VTKFile

        path = self.path.with_name(f"{self.path.stem}_{u.name}.pvd")
        try:
            if u.name not in self._vtk:
                self._vtk[u.name] = VTKFile(self.comm, str(path), "w")
            self._vtk[u.name].write_function(u, t)
        except RuntimeError as err:
            raise _write_failed(path, f"writing {u.name!r} at {t:g}", err) from None

    @property
    def times(self) -> dict[str, list[float]]:
        """The times written so far, per field name [s]."""
        return {k: list(v) for k, v in self._times.items()}

    def close(self) -> None:
        """Close the file (collective; idempotent)."""
        if not self._closed:
            self._closed = True
            try:
                self._file.close()
                for vtk in self._vtk.values():
                    vtk.close()
            except RuntimeError as err:
                raise _write_failed(self.path, "closing the file", err) from None
            finally:  # the C++ writers go now, inside the run's folder, not at a later GC
                self._vtk.clear()
                self._file = None

    def __enter__(self) -> FieldWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
