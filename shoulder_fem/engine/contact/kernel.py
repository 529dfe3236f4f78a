"""The compiled segment kernel (``segments.c``): the cut, the gaps and the segment tangent.

The numpy code of :mod:`~.points` and :mod:`~.segment_tangent` works every (slave piece,
master triangle) pair, and every perturbed copy of one, as a row of its arrays; its temporaries
cost more than the arithmetic (measured at ``paper``, part 1: the segment tangent 0.35 s and
the cut 0.05 s per evaluation, 62 % of the run). ``segments.c`` does the same arithmetic one
pair at a time. It is compiled with the system's C compiler (the one FFCx compiles the forms
with) on first use, into dolfinx's form cache under a name that holds the source's digest, and
loaded with cffi. The gaps of the cut's points (slave positions, master nodes and weights,
normals, gaps) are one pass over the points (numpy: 2.7 s of evaluations at ``paper``, part 1;
compiled, 0.4 s).

``SHOULDER_FEM_CONTACT_KERNEL=numpy`` selects the numpy code (the reference the tests compare
with); without a working compiler the numpy code runs, after one warning.
"""

from __future__ import annotations

import hashlib
import logging
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np

__all__ = ["CFLAGS", "Kernel", "build_library", "load"]

log = logging.getLogger(__name__)

#: Compiler flags (those of the hot forms, :data:`shoulder_fem.engine.fem.JIT_PARAMS`).
CFLAGS = ("-O2", "-g0", "-fno-math-errno", "-fPIC", "-shared")
_SOURCE = Path(__file__).with_name("segments.c")
_CDEF = """
long sf_cut(long M, const double *P, const double *ns, const double *T, int nq,
            const double *mu, const double *w, long cap, long *rr, double *lam, double *beta,
            double *W);
void sf_tangent(long M, int ns, int nm, const double *Y, const long *cols, const long *mv,
                const double *tmu, const double *ref_area, const double *lam_f, int nq,
                const double *mu, const double *w, int augmented, double penalty,
                double smoothing, double depth, double h, double near, double *blk,
                char *central);
void sf_gaps(long n, int nn, const long *facet, const long *snodes, const double *N,
             const double *x, const long *t, const double *bary3, const long *index,
             const long *parent, const double *tri_mu, const double *mx, long *m_idx,
             double *bary, double *xq, double *nrm, double *g);
"""
_loaded: dict[str, Kernel | None] = {}


def _cache_dir() -> Path:
    try:
        import dolfinx.jit

        return Path(dolfinx.jit.get_parameters()["cache_dir"]).expanduser()
    except Exception:  # pragma: no cover - dolfinx is always there in this project
        return Path(tempfile.gettempdir())


def build_library(source: Path) -> Path:
    """The shared library of ``source``, compiled once per source digest and flags."""
    code = source.read_bytes()
    digest = hashlib.sha1(code + " ".join(CFLAGS).encode()).hexdigest()[:16]
    cache = _cache_dir()
    lib = cache / f"shoulder_fem_segments_{digest}.so"
    if lib.exists():
        return lib
    cache.mkdir(parents=True, exist_ok=True)
    cc = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        raise OSError("no C compiler (cc or gcc) on the PATH")
    fd, tmp = tempfile.mkstemp(prefix=lib.stem + ".", suffix=".tmp", dir=cache)
    os.close(fd)
    try:
        run = subprocess.run(
            [cc, *CFLAGS, str(source), "-o", tmp, "-lm"], capture_output=True, text=True
        )
        if run.returncode != 0:
            raise OSError(f"{cc} failed on {source}: {run.stderr.strip()[:500]}")
        os.replace(tmp, lib)  # atomic: a rank or a run compiling beside us writes the same file
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return lib


def _ptr(ffi, ctype: str, a: np.ndarray):
    return ffi.cast(ctype, a.ctypes.data)


def _ptrs(ffi, *arrays: np.ndarray) -> list:
    """C pointers to contiguous int64 (``long *``) or float64 (``double *``) arrays."""
    kinds = {np.dtype(np.int64): "long *", np.dtype(np.float64): "double *"}
    return [_ptr(ffi, kinds[a.dtype], a) for a in arrays]


class Kernel:
    """The loaded library (:func:`load`)."""

    def __init__(self, path: Path):
        import cffi

        self.ffi = cffi.FFI()
        self.ffi.cdef(_CDEF)
        self.lib = self.ffi.dlopen(str(path))
        self.path = path

    def cut(self, P, ns, tri, rule):
        """Points of the pieces ``P`` (M, 3, 3) on the triangles ``tri`` (M, 3, 3).

        ``ns`` (M, 3): the pieces' unit normals; ``rule``: (mu, w) of the rule on a fan
        triangle. Returns (rr, lam, beta, W): the pair of every point, its barycentric
        coordinates on the piece and on the master triangle (its own vertex order), and its
        weight as a fraction of the piece's area; as ``fan_rule`` and ``barycentric_2d`` on
        ``overlap_polygons``.
        """
        ffi = self.ffi
        P, ns, tri = (np.ascontiguousarray(a, dtype=np.float64) for a in (P, ns, tri))
        mu = np.ascontiguousarray(rule[0], dtype=np.float64)
        w = np.ascontiguousarray(rule[1], dtype=np.float64)
        M = len(P)
        cap = max(1024, 4 * len(w) * M)  # the centroid fan: a triangle per polygon vertex
        while True:
            rr = np.empty(cap, dtype=np.int64)
            lam, beta, W = np.empty((cap, 3)), np.empty((cap, 3)), np.empty(cap)
            n = self.lib.sf_cut(
                M,
                _ptr(ffi, "double *", P),
                _ptr(ffi, "double *", ns),
                _ptr(ffi, "double *", tri),
                len(w),
                _ptr(ffi, "double *", mu),
                _ptr(ffi, "double *", w),
                cap,
                _ptr(ffi, "long *", rr),
                _ptr(ffi, "double *", lam),
                _ptr(ffi, "double *", beta),
                _ptr(ffi, "double *", W),
            )
            if n < 0:
                raise ValueError(f"segment rule of {len(w)} points: at most 16 supported")
            if n <= cap:
                return rr[:n], lam[:n], beta[:n], W[:n]
            cap = n

    def tangent(self, pair, Y, cols, m_vert, tri_mu, ref_area, lam_f, rule, ns_nodes, h, near):
        """Tangent blocks (M, k, 3, k, 3) of pairs at node positions ``Y`` (M, k, 3).

        The arguments as :func:`~.segment_tangent.segment_tangent_blocks` holds them; ``h``
        the difference step, ``near`` the kink distance under which a pair's are central.
        Returns (blk, central (M,) bool).
        """
        ffi = self.ffi
        M, k = Y.shape[:2]
        Y = np.ascontiguousarray(Y, dtype=np.float64)
        cols = np.ascontiguousarray(cols, dtype=np.int64)
        m_vert = np.ascontiguousarray(m_vert, dtype=np.int64)
        ref_area = np.ascontiguousarray(ref_area, dtype=np.float64)
        lam_f = np.ascontiguousarray(lam_f, dtype=np.float64)
        mu = np.ascontiguousarray(rule[0], dtype=np.float64)
        w = np.ascontiguousarray(rule[1], dtype=np.float64)
        if tri_mu is None:
            tmu = ffi.NULL
        else:
            tri_mu = np.ascontiguousarray(tri_mu, dtype=np.float64)
            tmu = _ptr(ffi, "double *", tri_mu)
        if len(w) > 16 or k > 12:
            raise ValueError(f"segment tangent: {len(w)} rule points, {k} nodes per pair")
        blk = np.empty((M, k, 3, k, 3))
        central = np.zeros(M, dtype=np.uint8)
        self.lib.sf_tangent(
            M,
            ns_nodes,
            k - ns_nodes,
            _ptr(ffi, "double *", Y),
            _ptr(ffi, "long *", cols),
            _ptr(ffi, "long *", m_vert),
            tmu,
            _ptr(ffi, "double *", ref_area),
            _ptr(ffi, "double *", lam_f),
            len(w),
            _ptr(ffi, "double *", mu),
            _ptr(ffi, "double *", w),
            int(pair.method == "augmented"),
            float(pair.penalty),
            float(pair.smoothing),
            float(pair.search_depth),
            float(h),
            float(near),
            _ptr(ffi, "double *", blk),
            _ptr(ffi, "char *", central),
        )
        return blk, central.astype(bool)

    def gaps(self, master, pts, slave_nodes, x_nodes):
        """Slave positions and the master side of segment points (``sf_gaps``).

        As ``evaluate_pair``'s xq, then :func:`~.points.segment_gaps`. Returns (xq, n, g,
        m_idx, bary).
        """
        ffi = self.ffi
        c = np.ascontiguousarray
        facet = c(pts["facet"], dtype=np.int64)
        N = c(pts["N"], dtype=np.float64)
        t = c(pts["m_tri"], dtype=np.int64)
        bary3 = c(pts["bary"], dtype=np.float64)
        snodes = c(slave_nodes, dtype=np.int64)
        x = c(x_nodes, dtype=np.float64)
        index = c(master.index, dtype=np.int64)
        mx = c(master.x, dtype=np.float64)
        n, nn = len(t), snodes.shape[1]
        keep = []  # the arrays the pointers point into, alive through the call
        if master.parent is not None:
            keep = [c(master.parent, dtype=np.int64), c(master.tri_mu, dtype=np.float64)]
            parent, tri_mu = _ptr(ffi, "long *", keep[0]), _ptr(ffi, "double *", keep[1])
            kk = 6
        else:
            parent = tri_mu = ffi.NULL
            kk = 3
        m_idx = np.empty((n, kk), dtype=np.int64)
        bary = np.empty((n, kk))
        xq, nrm, g = np.empty((n, 3)), np.empty((n, 3)), np.empty(n)
        inputs = _ptrs(ffi, facet, snodes, N, x, t, bary3, index)
        outputs = _ptrs(ffi, mx, m_idx, bary, xq, nrm, g)
        self.lib.sf_gaps(n, nn, *inputs, parent, tri_mu, *outputs)
        del keep
        return xq, nrm, g, m_idx, bary


def load() -> Kernel | None:
    """The compiled kernel, or None (numpy selected, or no compiler: warned once)."""
    choice = os.environ.get("SHOULDER_FEM_CONTACT_KERNEL", "c").strip().lower()
    if choice not in ("c", "numpy"):
        raise ValueError(f"SHOULDER_FEM_CONTACT_KERNEL = {choice!r}: expected 'c' or 'numpy'")
    if choice == "numpy":
        return None
    if "c" not in _loaded:
        try:
            _loaded["c"] = Kernel(build_library(_SOURCE))
        except (OSError, ImportError) as err:
            log.warning(
                "contact: the compiled segment kernel is not available (%s); "
                "the numpy code runs instead (slower, the same results)",
                err,
            )
            _loaded["c"] = None
    return _loaded["c"]
