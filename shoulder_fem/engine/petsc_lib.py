"""What petsc4py 3.18 does not expose, asked of the loaded PETSc library through ctypes."""

from __future__ import annotations

import functools

from petsc4py import PETSc

__all__ = ["line_search_maxstep", "options_used"]


@functools.cache
def _petsc_library():
    """The loaded PETSc library through ctypes (for what petsc4py 3.18 does not expose), or None.

    Found and opened once per process (every ``l2`` retry asks for the line search's step).
    """
    import ctypes
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
    import ctypes

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
    import ctypes

    lib = _petsc_library()
    if lib is None or not hasattr(lib, "PetscOptionsUsed"):
        return None
    query = lib.PetscOptionsUsed

    def used(name: str) -> bool:
        flag = ctypes.c_int(0)
        return query(None, name.encode(), ctypes.byref(flag)) == 0 and bool(flag.value)

    return used
