"""``J += C`` for AIJ matrices whose patterns are nested (C's within J's): :class:`SubsetAdd`.

PETSc's ``MatAXPY`` with ``SUBSET_NONZERO_PATTERN`` goes through ``MatSetValues`` row by row, a
search for every entry: at ``coarse``, part 1 to 30 deg, its 848 calls took 9.8 s of a 93 s
run, more than the products Pᵀ K P they add (5.6 s). Here a compiled walk (``csr_add.c``) goes
along each row of J and of C at once, in the matrices' own arrays: nothing is copied or kept.
Each entry of J gets the same one addition as with ``MatAXPY``: the sums are the same to the
last bit. C's pattern is checked against J's (a walk that only counts) whenever either pattern
is new (their PETSc ids and nonzero states).

A numpy version (positions found by a sorted search, then one indexed add per block) was
measured first: at ``coarse`` it cut the sums from 14.7 to 10.9 s of the reduction but raised
the run's peak memory from 385 to 430 MB (the positions and the keys of J's entries).
"""

from __future__ import annotations

import functools
import logging
from pathlib import Path

from mpi4py import MPI
from petsc4py import PETSc

from shoulder_fem.engine.petsc_lib import PETSC_INT64, aij_blocks, nonzero_key

__all__ = ["SubsetAdd"]

log = logging.getLogger(__name__)

_AIJ = (PETSc.Mat.Type.SEQAIJ, PETSc.Mat.Type.MPIAIJ)
_SOURCE = Path(__file__).with_name("csr_add.c")
_CDEF = """
long sf_csr_add32(long m, const int32_t *ji, const int32_t *jj, double *ja, const int32_t *ci,
                  const int32_t *cj, const double *ca, const int32_t *jmap,
                  const int32_t *cmap, int add);
long sf_csr_add64(long m, const int64_t *ji, const int64_t *jj, double *ja, const int64_t *ci,
                  const int64_t *cj, const double *ca, const int64_t *jmap,
                  const int64_t *cmap, int add);
"""


@functools.cache
def _load():
    """The compiled walk (ffi, function, C integer type), or None (no compiler: warned once)."""
    try:
        import cffi

        from shoulder_fem.engine.contact.kernel import build_library

        ffi = cffi.FFI()
        ffi.cdef(_CDEF)
        lib = ffi.dlopen(str(build_library(_SOURCE)))
    except (OSError, ImportError) as err:
        log.warning("the compiled J += C is not available (%s): PETSc's MatAXPY instead", err)
        return None
    if PETSC_INT64:
        return ffi, lib.sf_csr_add64, "int64_t *"
    return ffi, lib.sf_csr_add32, "int32_t *"


class SubsetAdd:
    """``J += C`` (C's pattern within J's; collective).

    Falls back to ``MatAXPY`` (which raises if C has an entry J has not) when the library's
    arrays or the compiled walk cannot be reached, for other matrix types, or when C's pattern
    is not within J's.
    """

    def __init__(self) -> None:
        self._key: tuple | None = None  # the patterns last checked
        #: sums done by the walk, pattern checks, and sums through MatAXPY (the fallback)
        self.walked = 0
        self.checks = 0
        self.fallbacks = 0

    def __call__(self, J: PETSc.Mat, C: PETSc.Mat) -> None:
        """``J += C`` (both assembled; collective)."""
        comm = J.getComm().tompi4py()
        kernel = _load()
        types = (J.getType(), C.getType())
        key = (nonzero_key(J), nonzero_key(C))
        usable = kernel is not None and None not in key
        usable = usable and types[0] == types[1] and types[0] in _AIJ
        if comm.allreduce(usable and key != self._key, op=MPI.LOR):  # a pattern is new
            self._key = key if usable and _walk(kernel, J, C, add=False) == 0 else None
            self.checks += 1
        # every rank takes the same path (MatAXPY is collective)
        if not comm.allreduce(usable and self._key == key, op=MPI.LAND):
            self._key = None
            self.fallbacks += 1
            J.axpy(1.0, C, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
            return
        _walk(kernel, J, C, add=True)
        self.walked += 1
        J.assemble()  # J's own state moves on (an MPIAIJ's blocks changed under it)


def _walk(kernel, J: PETSc.Mat, C: PETSc.Mat, add: bool) -> int:
    """C's entries that J has not (``add``: and J += C); both matrices' local blocks."""
    ffi, function, int_p = kernel
    missing = 0
    with aij_blocks(J, write=add) as jblocks, aij_blocks(C, write=False) as cblocks:
        for (m, ji, jj, ja, jmap), (mc, ci, cj, ca, cmap) in zip(jblocks, cblocks, strict=True):
            if m != mc:
                return max(1, mc)
            missing += function(
                m,
                ffi.cast(int_p, ji),
                ffi.cast(int_p, jj),
                ffi.cast("double *", ja),
                ffi.cast(int_p, ci),
                ffi.cast(int_p, cj),
                ffi.cast("double *", ca),
                ffi.cast(int_p, jmap),
                ffi.cast(int_p, cmap),
                int(add),
            )
    return missing
