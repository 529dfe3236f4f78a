"""What petsc4py 3.18 does not expose, asked of the loaded PETSc library through ctypes."""

from __future__ import annotations

import contextlib
import ctypes
import functools
from collections.abc import Iterator

import numpy as np
from petsc4py import PETSc

__all__ = ["PETSC_INT64", "aij_blocks", "line_search_maxstep", "nonzero_key", "options_used"]


@functools.cache
def _petsc_library():
    """The loaded PETSc library through ctypes (for what petsc4py 3.18 does not expose), or None.

    Found and opened once per process (every ``l2`` retry asks for the line search's step).
    """
    import glob

    import petsc4py

    config = petsc4py.get_config()
    found = sorted(
        glob.glob(f"{config['PETSC_DIR']}/{config.get('PETSC_ARCH', '')}/lib/libpetsc*.so*")
    )
    if not found:
        return None
    try:
        return ctypes.CDLL(found[0])  # the same library petsc4py loaded: its database
    except OSError:
        return None


def line_search_maxstep(snes: PETSc.SNES) -> float | None:
    """The largest step length of ``snes``'s line search now (``-snes_linesearch_maxstep``).

    ``SNESLineSearchGetTolerances`` through ctypes: petsc4py 3.18 has no SNESLineSearch. None
    when the library cannot be asked.
    """
    lib = _petsc_library()
    if lib is None or not hasattr(lib, "SNESLineSearchGetTolerances"):
        return None
    search, maxstep = ctypes.c_void_p(), ctypes.c_double()
    if lib.SNESGetLineSearch(ctypes.c_void_p(snes.handle), ctypes.byref(search)) != 0:
        return None
    # (linesearch, steptol, maxstep, rtol, atol, ltol, max_its): NULL for the others
    code = lib.SNESLineSearchGetTolerances(
        search, None, ctypes.byref(maxstep), None, None, None, None
    )
    return float(maxstep.value) if code == 0 else None


def options_used():
    """``PetscOptionsUsed`` of the loaded PETSc library (petsc4py 3.18 does not expose it)."""
    lib = _petsc_library()
    if lib is None or not hasattr(lib, "PetscOptionsUsed"):
        return None
    query = lib.PetscOptionsUsed

    def used(name: str) -> bool:
        flag = ctypes.c_int(0)
        return query(None, name.encode(), ctypes.byref(flag)) == 0 and bool(flag.value)

    return used


def nonzero_key(mat: PETSc.Mat) -> tuple[int, int] | None:
    """``mat``'s PETSc object id and nonzero state, or None when the library cannot be asked.

    The id is never reused within a process; the state takes a new value whenever the
    matrix's pattern changes.
    """
    lib = _petsc_library()
    if lib is None or not hasattr(lib, "MatGetNonzeroState"):
        return None
    ident, state = ctypes.c_int64(), ctypes.c_int64()
    handle = ctypes.c_void_p(mat.handle)
    if lib.PetscObjectGetId(handle, ctypes.byref(ident)) != 0:
        return None
    if lib.MatGetNonzeroState(handle, ctypes.byref(state)) != 0:
        return None
    return int(ident.value), int(state.value)


@contextlib.contextmanager
def aij_blocks(mat: PETSc.Mat, write: bool) -> Iterator[list[tuple[int, int, int, int, int]]]:
    """The local blocks of an assembled AIJ matrix, as raw CSR arrays (no copies).

    One block for SeqAIJ; the diagonal and the off-diagonal block for MPIAIJ. Each is (rows,
    address of the row offsets, of the column numbers, of the values, of the columns' global
    ids or 0 where the local numbers are the global order's: the off-diagonal block's own
    numbering is the one that has them). ``write``: the values may be changed
    (``MatSeqAIJGetArray``, else ``...GetArrayRead``). Everything is given back on leaving.
    Raises ``OSError`` when the library cannot be asked.
    """
    lib = _petsc_library()
    if lib is None or not hasattr(lib, "MatMPIAIJGetSeqAIJ"):
        raise OSError("the PETSc library cannot be asked for a matrix's arrays")
    handle = ctypes.c_void_p(mat.handle)
    if mat.getType() == PETSc.Mat.Type.MPIAIJ:
        diag, off, colmap = ctypes.c_void_p(), ctypes.c_void_p(), ctypes.c_void_p()
        code = lib.MatMPIAIJGetSeqAIJ(
            handle, ctypes.byref(diag), ctypes.byref(off), ctypes.byref(colmap)
        )
        if code != 0:
            raise OSError("MatMPIAIJGetSeqAIJ failed")
        blocks = [(diag, 0), (off, colmap.value or 0)]
    else:
        blocks = [(handle, 0)]
    get, give = (
        (lib.MatSeqAIJGetArray, lib.MatSeqAIJRestoreArray)
        if write
        else (lib.MatSeqAIJGetArrayRead, lib.MatSeqAIJRestoreArrayRead)
    )
    with contextlib.ExitStack() as stack:  # each array given back, last taken first
        out = []
        for block, colmap_at in blocks:
            n, done = ctypes.c_int64(0) if PETSC_INT64 else ctypes.c_int32(0), ctypes.c_int(0)
            ia, ja, values = ctypes.c_void_p(), ctypes.c_void_p(), ctypes.c_void_p()
            # shift 0, not symmetric, not inode-compressed: the matrix's own arrays
            row_ij = (block, 0, 0, 0, ctypes.byref(n), ctypes.byref(ia), ctypes.byref(ja))
            if lib.MatGetRowIJ(*row_ij, ctypes.byref(done)) != 0 or not done.value:
                raise OSError("MatGetRowIJ failed")
            stack.callback(lib.MatRestoreRowIJ, *row_ij, ctypes.byref(done))
            if get(block, ctypes.byref(values)) != 0:
                raise OSError("MatSeqAIJGetArray failed")
            stack.callback(give, block, ctypes.byref(values))
            out.append((int(n.value), ia.value or 0, ja.value or 0, values.value or 0, colmap_at))
        yield out


#: Whether PETSc's integers are 64-bit here (Debian's build: 32).
PETSC_INT64 = np.dtype(PETSc.IntType).itemsize == 8
