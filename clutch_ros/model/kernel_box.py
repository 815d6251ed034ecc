"""The spline box problem of one step, plain Python compiled by :mod:`clutch_ros.model.kernel`.

The compiled loop's part of the box laws (``coulomb``, passive ``ff_t`` / ``ff_v``): the
H-norm projection of the all-stuck force onto the law's box (see
:mod:`clutch_ros.model.spline_passive`), found by the warm-started active-set iteration with
projected Gauss-Seidel as fallback, the same algorithm as the numpy path. Forces in [N],
positions in [m]. Nothing is allocated or sliced per step: the loop allocates the scratch
once per series (``fs`` float rows, ``bb`` flag rows, ``ib`` index rows, ``gss`` N x N; the
row constants below name them) and the functions index it, and the per-dt matrices, directly
(``[e, i, j]``).
This module does not import numba; :func:`clutch_ros.model.kernel._compiled` compiles its
functions in place (they stay plain Python, and correct, without numba).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:  # annotations only: this module stays plain Python for numba
    from clutch_ros.model.arraytypes import BoolArray, FloatArray, IntArray

__all__ = ["BOX", "BOX_FUNCTIONS", "COULOMB", "FF_T", "FF_V", "LINEAR", "NONE", "SCRATCH_ROWS",
           "SIGMA", "STUCK", "VISCOUS", "mat_vec"]

#: kinds of law of the compiled loop (the registry, :mod:`~.laws`, gives each law its code):
#: no force, linear (T enters the work vector), held viscous force, box problem
NONE, LINEAR, VISCOUS, BOX = 0, 1, 2, 3
#: variants of the box problem (:func:`_box_apply`)
COULOMB, FF_T, FF_V = 0, 1, 2
_COULOMB, _FF_T, _FF_V = COULOMB, FF_T, FF_V
_MAX_ACTIVE_SET_ITERATIONS = 64
_MAX_GAUSS_SEIDEL_SWEEPS = 10000
# rows of the float scratch fs: printed force, normal forces (N + 1), box, stick force, the
# forces, dz, polished forces, rhs, trial sides, the warm sides σ
_DES, _NORMAL, _LO, _HI, _FSTICK, _F, _DZ, _POLISHED, _RHS, _TSIGMA, SIGMA, _V = range(12)
SCRATCH_ROWS = 12
# rows of the flag scratch bb: the warm stuck mask, trial mask, violated conditions
STUCK, _TSTUCK, _BAD_STUCK, _BAD_SLIDE = range(4)
#: compiled in this order (helpers first)
BOX_FUNCTIONS = ("mat_vec", "_lu_solve", "_box_forces", "_violations", "_gauss_seidel",
                 "_box_solve", "_box_apply")


def mat_vec(mt: FloatArray, e: int, w: FloatArray, wrow: int, ncols: int, nrows: int,
            out: FloatArray, orow: int) -> None:
    """``out[orow, r] = Σ_c mt[e, c, r] · w[wrow, c]`` for r < nrows (``mt[e]``: M transposed).

    Each sum runs in the order of c from 0.0, as ``acc += m[r, c] * w[c]`` would (same
    result to the bit); four rows at a time in independent accumulators, so the adds
    pipeline (and may be vectorised across the rows) instead of waiting on one chain.
    """
    r = 0
    while r + 4 <= nrows:
        a0 = a1 = a2 = a3 = 0.0
        for c in range(ncols):
            wc = w[wrow, c]
            a0 += mt[e, c, r] * wc
            a1 += mt[e, c, r + 1] * wc
            a2 += mt[e, c, r + 2] * wc
            a3 += mt[e, c, r + 3] * wc
        out[orow, r] = a0
        out[orow, r + 1] = a1
        out[orow, r + 2] = a2
        out[orow, r + 3] = a3
        r += 4
    while r < nrows:
        acc = 0.0
        for c in range(ncols):
            acc += mt[e, c, r] * w[wrow, c]
        out[orow, r] = acc
        r += 1


def _lu_solve(a: FloatArray, b: FloatArray, m: int) -> None:
    """Solve ``a[:m, :m] x = b[:m]`` in place (Gaussian elimination, partial pivoting)."""
    for k in range(m):
        p = k
        big = abs(a[k, k])
        for i in range(k + 1, m):
            if abs(a[i, k]) > big:
                big = abs(a[i, k])
                p = i
        if p != k:
            for j in range(m):
                a[k, j], a[p, j] = a[p, j], a[k, j]
            b[k], b[p] = b[p], b[k]
        for i in range(k + 1, m):
            factor = a[i, k] / a[k, k]
            if factor != 0.0:
                for j in range(k + 1, m):
                    a[i, j] -= factor * a[k, j]
                b[i] -= factor * b[k]
    for k in range(m - 1, -1, -1):
        acc = b[k]
        for j in range(k + 1, m):
            acc -= a[k, j] * b[j]
        b[k] = acc / a[k, k]


def _box_forces(gm: FloatArray, e: int, n: int, fs: FloatArray, bb: BoolArray, ib: IntArray,
                gss: FloatArray, st_row: int, sg_row: int, f_row: int) -> None:
    """Write one active set's forces to ``fs[f_row]``: sliding at hi (σ > 0) or lo, stuck solved.

    The set is ``bb[st_row]`` (stuck) with sides ``fs[sg_row]``; ``gm[e]`` is G = ∂z⁺/∂f.
    """
    n_st = 0
    n_sl = 0
    for i in range(n):
        fs[f_row, i] = fs[_HI, i] if fs[sg_row, i] > 0.0 else fs[_LO, i]
        if bb[st_row, i]:
            ib[0, n_st] = i
            n_st += 1
        else:
            ib[1, n_sl] = i
            n_sl += 1
    if n_st == 0:
        return
    if n_sl == 0:
        for i in range(n):
            fs[f_row, i] = fs[_FSTICK, i]
        return
    rhs = fs[_RHS]
    for r in range(n_st):
        a = ib[0, r]
        for c in range(n_st):
            gss[r, c] = gm[e, a, ib[0, c]]
        acc = 0.0
        for c in range(n_sl):
            b = ib[1, c]
            acc += gm[e, a, b] * (fs[f_row, b] - fs[_FSTICK, b])
        rhs[r] = acc
    _lu_solve(gss, rhs, n_st)
    for r in range(n_st):
        a = ib[0, r]
        fs[f_row, a] = fs[_FSTICK, a] - rhs[r]


def _violations(gt: FloatArray, e: int, n: int, fs: FloatArray, bb: BoolArray, st_row: int,
                sg_row: int, f_row: int) -> bool:
    """Mark the set's violated conditions (``bb`` rows); return True if any (``gt``: Gᵀ)."""
    for j in range(n):
        fs[_V, j] = fs[f_row, j] - fs[_FSTICK, j]
    mat_vec(gt, e, fs, _V, n, n, fs, _DZ)
    fmax = 0.0
    wmax = 0.0
    zmax = 0.0
    for i in range(n):
        acc = fs[_DZ, i]
        fmax = max(fmax, abs(fs[_FSTICK, i]))
        wmax = max(wmax, fs[_HI, i] - fs[_LO, i])
        zmax = max(zmax, abs(acc))
    tol_f = 1e-12 * (fmax + wmax + 1.0)
    tol_z = 1e-12 * (zmax + 1e-15)
    anybad = False
    for i in range(n):
        f, stuck = fs[f_row, i], bb[st_row, i]
        bad_stuck = stuck and (f > fs[_HI, i] + tol_f or f < fs[_LO, i] - tol_f)
        bad_slide = (not stuck) and fs[_HI, i] > fs[_LO, i] and \
            fs[sg_row, i] * fs[_DZ, i] < -tol_z
        bb[_BAD_STUCK, i] = bad_stuck
        bb[_BAD_SLIDE, i] = bad_slide
        anybad = anybad or bad_stuck or bad_slide
    return anybad


def _gauss_seidel(hm: FloatArray, e: int, n: int, fs: FloatArray) -> None:
    """Projected Gauss-Seidel on the box QP (converges for any SPD H) into ``fs[_F]``."""
    fmax = 0.0
    for i in range(n):
        fs[_F, i] = min(max(fs[_FSTICK, i], fs[_LO, i]), fs[_HI, i])
        fmax = max(fmax, abs(fs[_FSTICK, i]))
    tol = 1e-13 * (fmax + 1.0)
    for _ in range(_MAX_GAUSS_SEIDEL_SWEEPS):
        change = 0.0
        for i in range(n):
            grad = 0.0
            for j in range(n):
                grad += hm[e, i, j] * (fs[_F, j] - fs[_FSTICK, j])
            new = min(max(fs[_F, i] - grad / hm[e, i, i], fs[_LO, i]), fs[_HI, i])
            change = max(change, abs(new - fs[_F, i]))
            fs[_F, i] = new
        if change <= tol:
            break


def _box_solve(gm: FloatArray, gt: FloatArray, hm: FloatArray, e: int, n: int, fs: FloatArray,
               bb: BoolArray, ib: IntArray, gss: FloatArray) -> None:
    """Projection onto the box from the warm set (updated in place); forces into ``fs[_F]``."""
    for _ in range(_MAX_ACTIVE_SET_ITERATIONS):
        _box_forces(gm, e, n, fs, bb, ib, gss, STUCK, SIGMA, _F)
        if not _violations(gt, e, n, fs, bb, STUCK, SIGMA, _F):
            return
        for i in range(n):
            if bb[_BAD_STUCK, i]:
                fs[SIGMA, i] = 1.0 if fs[_F, i] > fs[_HI, i] else -1.0
                bb[STUCK, i] = False
            if bb[_BAD_SLIDE, i]:
                bb[STUCK, i] = True
    _gauss_seidel(hm, e, n, fs)
    for i in range(n):
        f, lo, hi = fs[_F, i], fs[_LO, i], fs[_HI, i]
        width = hi - lo
        bb[_TSTUCK, i] = f > lo + 1e-9 * width and f < hi - 1e-9 * width
        fs[_TSIGMA, i] = 1.0 if f >= hi - 1e-9 * width else -1.0
    _box_forces(gm, e, n, fs, bb, ib, gss, _TSTUCK, _TSIGMA, _POLISHED)
    if not _violations(gt, e, n, fs, bb, _TSTUCK, _TSIGMA, _POLISHED):
        for i in range(n):
            fs[_F, i] = fs[_POLISHED, i]
    for i in range(n):
        bb[STUCK, i] = bb[_TSTUCK, i]
        fs[SIGMA, i] = fs[_TSIGMA, i]


def _box_apply(variant: int, work: FloatArray, lay: tuple[int, int, int, int], torque: float,
               scale: float, gain: float,
               box: tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray], e: int,
               scratch: tuple[FloatArray, BoolArray, IntArray, FloatArray]) -> None:
    """Held spline forces of the box laws (coulomb, passive ff_t / ff_v) into ``work``.

    ``lay`` = (head, s0, f0, nlam): the work vector's head length, first law state, first
    force, lamella count. ``box`` = (kts, nts, gm, gt, hm): per dt entry ``e`` the stick-force
    and normal-force matrices transposed (head, N) and (head, N + 1), so the products run
    down contiguous rows (same sums, same order, :func:`mat_vec`), then G, Gᵀ and H.
    ``scratch`` = (fs, bb, ib, gss) (module docstring). ``work`` is the work vector as a
    (1, size) row. The warm set is ``bb[STUCK]``, ``fs[SIGMA]``.
    """
    head, s0, f0, nlam = lay
    kts, nts, gm, gt, hm = box
    fs, bb, ib, gss = scratch
    anyd = False
    for i in range(nlam):
        if variant == _FF_T:
            d = gain * torque - work[0, s0]
        elif variant == _FF_V:
            d = work[0, s0 + i] * (gain * torque)
        else:
            d = 1.0
        fs[_DES, i] = d
        anyd = anyd or d != 0.0
    if scale <= 0.0 or not anyd:
        for i in range(nlam):
            work[0, f0 + i] = 0.0
        return
    mat_vec(nts, e, work, 0, head, nlam + 1, fs, _NORMAL)
    mat_vec(kts, e, work, 0, head, nlam, fs, _FSTICK)
    for i in range(nlam):
        a = fs[_NORMAL, i] if fs[_NORMAL, i] > 0.0 else 0.0
        b = fs[_NORMAL, i + 1] if fs[_NORMAL, i + 1] > 0.0 else 0.0
        bound = (a + b) * scale
        if variant == _COULOMB:
            fs[_LO, i], fs[_HI, i] = -bound, bound
        else:
            d = fs[_DES, i]
            fs[_HI, i] = min(max(d, 0.0), bound)
            fs[_LO, i] = max(min(d, 0.0), -bound)
    _box_solve(gm, gt, hm, e, nlam, fs, bb, ib, gss)
    for i in range(nlam):
        work[0, f0 + i] = fs[_F, i]
