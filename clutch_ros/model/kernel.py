"""Compiled per-sample loop of the pack model (numba), used by :func:`simulate` when available.

:func:`~clutch_ros.model.simulate.simulate` (and so replay, fit and
:func:`~clutch_ros.model.estimator.estimate_batch`) runs its per-sample loop here with
``engine="kernel"`` or ``"auto"`` (the default); the numpy path
(:meth:`~clutch_ros.model.pack.PackModel._advance`, one Python call per sample) stays the
reference (``engine="numpy"``) and the fallback. The compiled loop performs the same steps in
the same order per sample (thesis Eqs. 11-27, :meth:`PackModel._advance`): μ at the start of
the step from the pack's own state (normal-force pressure, film, temperature), the spline
law's held forces, the exact ZOH ``x⁺ = M w`` (M = [Φ | Γ] of the step's dt, built by the
model's discretisation cache), then the oil film and thermal states with the inputs held. Laws:

- ``none``, ``ff_t_printed``: linear; T enters the work vector;
- ``ff_v_printed``: ``F_fn = κ T w_n`` held;
- ``coulomb``, ``ff_t``, ``ff_v`` (passive): the H-norm projection of the all-stuck force
  onto the law's box (see :mod:`clutch_ros.model.spline_passive`), found by the same
  warm-started active-set iteration with projected Gauss-Seidel as fallback. The solution of
  the box problem is unique, so the compiled and the numpy solver agree to rounding (the
  products are summed in a different order; tests/model/test_kernel.py states the tolerances
  it checks).

Compiled code is cached on disk (``cache=True``) in ``NUMBA_CACHE_DIR`` (default: a
``numba`` folder in the user cache dir, ``$XDG_CACHE_HOME`` or ``~/.cache``, under
``clutch_ros``), so only the first call after install pays the few seconds of compilation.

Fallback, never silent: with ``engine="auto"``, if numba cannot be imported, compilation
fails, or ``CLUTCH_KERNEL=0`` is set, the numpy path runs, the reason is logged (a warning,
once per process; info for the explicit switch) and kept in :func:`unavailable_reason`.
``engine="kernel"`` raises :class:`KernelUnavailableError` instead of falling back.
"""

from __future__ import annotations

import logging
import math
import os
from pathlib import Path

import numpy as np

from clutch_ros.model.errors import InputError, ModelError
from clutch_ros.model.slip import lowpass_series as _lowpass_numpy

__all__ = ["ENGINES", "KernelUnavailableError", "LAW_CODES", "available", "check_engine",
           "lowpass_series", "run_loop", "unavailable_reason"]

_log = logging.getLogger(__name__)

#: accepted values of simulate()'s ``engine`` argument
ENGINES = ("auto", "kernel", "numpy")

_NONE, _LINEAR, _VISCOUS, _BOX = 0, 1, 2, 3
_COULOMB, _FF_T, _FF_V = 0, 1, 2
#: law name -> (kind, box variant) of the compiled loop
LAW_CODES = {"none": (_NONE, 0), "ff_t_printed": (_LINEAR, 0), "ff_v_printed": (_VISCOUS, 0),
             "coulomb": (_BOX, _COULOMB), "ff_t": (_BOX, _FF_T), "ff_v": (_BOX, _FF_V)}
_MAX_ACTIVE_SET_ITERATIONS = 64
_MAX_GAUSS_SEIDEL_SWEEPS = 10000

#: loop: the compiled loop once numba is imported; reason: why the kernel cannot be used
_state: dict = {"loop": None, "reason": None, "numba_error": None}


class KernelUnavailableError(ModelError):
    """``engine="kernel"`` was asked for but the compiled kernel cannot run (says why)."""


def _cache_dir() -> str:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return str(Path(base) / "clutch_ros" / "numba")


def check_engine(engine: str) -> str:
    """Return ``engine`` if it is one of :data:`ENGINES`, else raise InputError."""
    if engine not in ENGINES:
        raise InputError(f"engine must be one of {', '.join(ENGINES)}, got {engine!r}")
    return engine


def available() -> bool:
    """Return True when the compiled loop can be used (numba imported, not switched off)."""
    return _compiled() is not None


def unavailable_reason() -> str | None:
    """Return why the kernel cannot be used (None while it can, or before the first try)."""
    return _state["reason"]


def _disable(reason: str, level: int = logging.WARNING) -> None:
    _state["loop"] = None
    _state["reason"] = reason
    _log.log(level, "model kernel: %s; numpy path", reason)


def _compiled():
    if _state["loop"] is not None or _state["reason"] is not None:
        return _state["loop"]
    if os.environ.get("CLUTCH_KERNEL", "1") == "0":
        _disable("switched off by CLUTCH_KERNEL=0", logging.INFO)
        return None
    os.environ.setdefault("NUMBA_CACHE_DIR", _cache_dir())
    try:
        # numba (LLVM) is slow to import (~0.3-0.5 s): loaded on the first simulate(), so
        # commands that never simulate start fast
        import numba
        from numba.core.errors import NumbaError
    except Exception as err:  # noqa: BLE001 - any import failure means: use numpy
        _disable(f"numba cannot be imported ({type(err).__name__}: {err})")
        return None
    _state["numba_error"] = NumbaError
    jit = numba.njit(cache=True, nogil=True)
    g = globals()
    g["_lowpass"] = jit(g["_lowpass"])
    for name in ("_mu", "_film_step", "_thermal_step", "_box_forces", "_violations",
                 "_gauss_seidel", "_box_solve", "_box_apply", "_loop"):
        func = g[name]  # helpers first: later functions call the compiled ones
        g[name] = func if hasattr(func, "py_func") else jit(func)
    _state["loop"] = g["_loop"]
    return _state["loop"]


# -- the per-sample code (plain Python; compiled by _compiled()) ------------------------------
# fr: mu_ref, temperature_slope, temperature_ref, pressure_loss_at_ref, pressure_ref,
#     stribeck_speed, static_ratio, film_depth, mu_min, film_thinning_time, film_recovery_time
# th: heat_capacity, conductance, oil_temperature


def _mu(fr, temperature, pressure, slip_speed, film):
    f_t = 1.0 + fr[1] * (temperature - fr[2])
    p = pressure if pressure > 0.0 else 0.0
    f_p = 1.0 - fr[3] * p / fr[4]
    x = slip_speed / fr[5]
    g = math.exp(-(x * x))
    f_w = 1.0 + (fr[6] - 1.0) * (g + (1.0 - g) * fr[7] * (1.0 - film))
    mu = fr[0] * f_t * f_p * f_w
    return mu if mu > fr[8] else fr[8]


def _film_step(fr, film, dt, pressure, slip_speed):
    x = slip_speed / fr[5]
    g = math.exp(-(x * x))
    p = pressure if pressure > 0.0 else 0.0
    thin = (p / fr[4]) * g / fr[9]
    rec = (1.0 - g) / fr[10]
    rate = thin + rec
    if rate <= 0.0:
        return film
    target = rec / rate
    return target + (film - target) * math.exp(-rate * dt)


def _thermal_step(th, temperature, dt, power):
    g = th[1]
    target = th[2] + power / g
    return target + (temperature - target) * math.exp(-dt * g / th[0])


def _box_forces(g, f_stick, lo, hi, stuck, sigma, f):
    """Write the forces of one active set: sliding at hi (σ > 0) or lo, stuck ones solved."""
    n = f.size
    n_st = 0
    for i in range(n):
        f[i] = hi[i] if sigma[i] > 0.0 else lo[i]
        if stuck[i]:
            n_st += 1
    if n_st == 0:
        return
    if n_st == n:
        f[:] = f_stick
        return
    st = np.empty(n_st, dtype=np.int64)
    sl = np.empty(n - n_st, dtype=np.int64)
    a = b = 0
    for i in range(n):
        if stuck[i]:
            st[a] = i
            a += 1
        else:
            sl[b] = i
            b += 1
    gss = np.empty((n_st, n_st))
    rhs = np.zeros(n_st)
    for r in range(n_st):
        for c in range(n_st):
            gss[r, c] = g[st[r], st[c]]
        acc = 0.0
        for c in range(n - n_st):
            acc += g[st[r], sl[c]] * (f[sl[c]] - f_stick[sl[c]])
        rhs[r] = acc
    x = np.linalg.solve(gss, rhs)
    for r in range(n_st):
        f[st[r]] = f_stick[st[r]] - x[r]


def _violations(g, f_stick, f, lo, hi, stuck, sigma, bad_stuck, bad_slide):
    """Mark the set's violated conditions; return True if any."""
    n = f.size
    dz = np.zeros(n)
    fmax = 0.0
    wmax = 0.0
    zmax = 0.0
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc += g[i, j] * (f[j] - f_stick[j])
        dz[i] = acc
        fmax = max(fmax, abs(f_stick[i]))
        wmax = max(wmax, hi[i] - lo[i])
        zmax = max(zmax, abs(acc))
    tol_f = 1e-12 * (fmax + wmax + 1.0)
    tol_z = 1e-12 * (zmax + 1e-15)
    anybad = False
    for i in range(n):
        bad_stuck[i] = stuck[i] and (f[i] > hi[i] + tol_f or f[i] < lo[i] - tol_f)
        bad_slide[i] = (not stuck[i]) and hi[i] > lo[i] and sigma[i] * dz[i] < -tol_z
        anybad = anybad or bad_stuck[i] or bad_slide[i]
    return anybad


def _gauss_seidel(h, f_stick, lo, hi, f):
    """Projected Gauss-Seidel on the box QP (converges for any SPD H)."""
    n = f.size
    fmax = 0.0
    for i in range(n):
        f[i] = min(max(f_stick[i], lo[i]), hi[i])
        fmax = max(fmax, abs(f_stick[i]))
    tol = 1e-13 * (fmax + 1.0)
    for _ in range(_MAX_GAUSS_SEIDEL_SWEEPS):
        change = 0.0
        for i in range(n):
            grad = 0.0
            for j in range(n):
                grad += h[i, j] * (f[j] - f_stick[j])
            new = min(max(f[i] - grad / h[i, i], lo[i]), hi[i])
            change = max(change, abs(new - f[i]))
            f[i] = new
        if change <= tol:
            break


def _box_solve(g, h, f_stick, lo, hi, stuck, sigma, f):
    """Projection onto the box from the warm set (updated in place); forces into ``f``."""
    n = f.size
    bad_stuck = np.zeros(n, dtype=np.bool_)
    bad_slide = np.zeros(n, dtype=np.bool_)
    for _ in range(_MAX_ACTIVE_SET_ITERATIONS):
        _box_forces(g, f_stick, lo, hi, stuck, sigma, f)
        if not _violations(g, f_stick, f, lo, hi, stuck, sigma, bad_stuck, bad_slide):
            return
        for i in range(n):
            if bad_stuck[i]:
                sigma[i] = 1.0 if f[i] > hi[i] else -1.0
                stuck[i] = False
            if bad_slide[i]:
                stuck[i] = True
    _gauss_seidel(h, f_stick, lo, hi, f)
    trial_stuck = np.zeros(n, dtype=np.bool_)
    trial_sigma = np.ones(n)
    for i in range(n):
        width = hi[i] - lo[i]
        trial_stuck[i] = f[i] > lo[i] + 1e-9 * width and f[i] < hi[i] - 1e-9 * width
        trial_sigma[i] = 1.0 if f[i] >= hi[i] - 1e-9 * width else -1.0
    polished = np.empty(n)
    _box_forces(g, f_stick, lo, hi, trial_stuck, trial_sigma, polished)
    if not _violations(g, f_stick, polished, lo, hi, trial_stuck, trial_sigma, bad_stuck,
                       bad_slide):
        f[:] = polished
    stuck[:] = trial_stuck
    sigma[:] = trial_sigma


def _box_apply(variant, work, head, s0, f0, nlam, torque, scale, gain, kmat, nmat, g, h,
               stuck, sigma):
    """Held spline forces of the box laws (coulomb, passive ff_t / ff_v) into ``work``."""
    des = np.empty(nlam)
    anyd = False
    for i in range(nlam):
        if variant == _FF_T:
            des[i] = gain * torque - work[s0]
        elif variant == _FF_V:
            des[i] = work[s0 + i] * (gain * torque)
        else:
            des[i] = 1.0
        anyd = anyd or des[i] != 0.0
    if scale <= 0.0 or not anyd:
        for i in range(nlam):
            work[f0 + i] = 0.0
        return
    normal = np.empty(nlam + 1)
    for r in range(nlam + 1):
        acc = 0.0
        for c in range(head):
            acc += nmat[r, c] * work[c]
        normal[r] = acc if acc > 0.0 else 0.0
    lo = np.empty(nlam)
    hi = np.empty(nlam)
    f_stick = np.empty(nlam)
    for i in range(nlam):
        bound = (normal[i] + normal[i + 1]) * scale
        if variant == _COULOMB:
            lo[i], hi[i] = -bound, bound
        else:
            d = des[i]
            hi[i] = min(max(d, 0.0), bound)
            lo[i] = max(min(d, 0.0), -bound)
        acc = 0.0
        for c in range(head):
            acc += kmat[i, c] * work[c]
        f_stick[i] = acc
    f = np.empty(nlam)
    _box_solve(g, h, f_stick, lo, hi, stuck, sigma, f)
    for i in range(nlam):
        work[f0 + i] = f[i]


def _loop(ms, inv, dts, press, omega, temp, sign, work, idx, consts, fr, th, law, variant,
          kmats, nmats, gmats, hmats, stuck, sigma, states, forces, temps, films, torque_out,
          record):
    """Run steps 1..n-1 of simulate() (PackModel._advance per sample); return (film, temp)."""
    nx, i_front, i_force, i_torque, s0, f0, nlam, head = (idx[0], idx[1], idx[2], idx[3],
                                                          idx[4], idx[5], idx[6], idx[7])
    area, c2k, k_na, gain, coef, film_on = (consts[0], consts[1], consts[2], consts[3],
                                            consts[4], consts[5])
    film = consts[6]
    cur_temp = consts[7]
    size = work.size
    x = np.empty(nx)
    n = press.size
    for k in range(1, n):
        j = k - 1
        t_in = temp[k]
        t_use = t_in if t_in == t_in else cur_temp
        zn = work[i_front]
        p_eq = zn * k_na if zn > 0.0 else 0.0
        mu = _mu(fr, t_use, p_eq, omega[k], film)
        load = mu * abs(sign[k])
        torque = c2k * load * zn if zn > 0.0 else 0.0
        work[i_force] = press[k] * area if press[k] > 0.0 else 0.0
        work[i_torque] = torque
        e = inv[j]
        if law == _VISCOUS:
            gt = gain * torque
            for i in range(nlam):
                work[f0 + i] = work[s0 + i] * gt
        elif law == _BOX:
            _box_apply(variant, work, head, s0, f0, nlam, torque, coef * load, gain,
                       kmats[e], nmats[e], gmats[e], hmats[e], stuck, sigma)
        m = ms[e]
        for r in range(nx):
            acc = 0.0
            for c in range(size):
                acc += m[r, c] * work[c]
            x[r] = acc
        work[:nx] = x
        if film_on > 0.0:
            film = _film_step(fr, film, dts[j], p_eq, omega[k])
        if t_in == t_in:
            cur_temp = t_in
        else:
            cur_temp = _thermal_step(th, t_use, dts[j], torque * abs(omega[k]))
        states[k] = x
        if record:
            forces[k] = work[f0:f0 + nlam]
        temps[k] = cur_temp
        films[k] = film
        torque_out[j] = torque
    return film, cur_temp


def _lowpass(dts, u, tau, out):
    """:func:`clutch_ros.model.slip.lowpass_series`'s loop (same float operations)."""
    y = u[0]
    out[0] = y
    for k in range(1, u.size):
        y = y + (-math.expm1(-dts[k - 1] / tau)) * (u[k] - y)
        out[k] = y


# -- the Python side -------------------------------------------------------------------------
def lowpass_series(t, u, time_constant: float, engine: str = "auto") -> np.ndarray:
    """Slip-speed low pass over a series, compiled (:func:`clutch_ros.model.slip.lowpass_series`).

    Same result as the numpy reference (to the last bit or two of ``expm1``); the engine
    chooses as for :func:`run_loop`.
    """
    tau = float(time_constant)
    u = np.asarray(u, dtype=float)
    if check_engine(engine) == "numpy" or u.size == 0 or tau <= 0.0:
        return _lowpass_numpy(t, u, time_constant)
    if _compiled() is None:
        if engine == "kernel":
            raise KernelUnavailableError(f"engine='kernel': {_state['reason']}")
        return _lowpass_numpy(t, u, time_constant)
    out = np.empty(u.size)
    try:
        _lowpass(np.diff(np.asarray(t, dtype=float)), np.ascontiguousarray(u), tau, out)
    except _state["numba_error"] as err:  # compilation failed: nothing ran
        _disable(f"compilation failed ({type(err).__name__}: {str(err).splitlines()[0]})")
        if engine == "kernel":
            raise KernelUnavailableError(f"engine='kernel': {_state['reason']}") from err
        return _lowpass_numpy(t, u, time_constant)
    return out


def _box_matrices(law_name, table, nlam, head):
    prefix = "coulomb" if law_name == "coulomb" else "passive"
    if law_name not in ("coulomb", "ff_t", "ff_v"):
        empty = np.zeros((len(table), 1, 1))
        return empty, empty, empty, empty
    stack = [np.ascontiguousarray([getattr(e, f"{prefix}_{name}") for e in table])
             for name in ("stick", "normal", "g", "h")]
    return tuple(stack)


def run_loop(model, table, inverse, dts, press, omega, temp, sign, states, forces, temps,
             films, engine: str = "auto"):
    """Run :func:`~clutch_ros.model.simulate.simulate`'s steps 1..n-1 compiled.

    Same arguments and effects as the numpy loop there (fills ``states[1:]``, ``forces[1:]``
    for laws that record them, ``temps[1:]``, ``films[1:]``; leaves ``model`` as the step
    loop does) and returns the law's torque per step [N m]. Returns None when the caller must
    run the numpy loop: ``engine="numpy"``, or ``"auto"`` with the kernel unavailable (the
    reason is logged, see the module docstring). ``engine="kernel"`` raises
    :class:`KernelUnavailableError` instead.
    """
    if check_engine(engine) == "numpy":
        return None
    law = model.law
    codes = LAW_CODES.get(law.name)
    loop = _compiled()
    if loop is None or codes is None:
        why = _state["reason"] if loop is None else f"no compiled code for law {law.name!r}"
        if engine == "kernel":
            raise KernelUnavailableError(f"engine='kernel': {why}")
        if codes is None:
            _log.warning("model kernel: %s; numpy path", why)
        return None
    lay = model.layout
    fr_p, th_p = model._fr, model.params.thermal
    fr = np.array([fr_p.mu_ref, fr_p.temperature_slope, fr_p.temperature_ref,
                   fr_p.pressure_loss_at_ref, fr_p.pressure_ref, fr_p.stribeck_speed,
                   fr_p.static_ratio, fr_p.film_depth, fr_p.mu_min, fr_p.film_thinning_time,
                   fr_p.film_recovery_time], dtype=float)
    th = np.array([th_p.heat_capacity, th_p.conductance, th_p.oil_temperature], dtype=float)
    ms = np.ascontiguousarray([e.M for e in table])
    kmats, nmats, gmats, hmats = _box_matrices(law.name, table, lay.lamella_count, lay.head)
    idx = np.array([lay.n_state, lay.i_front, lay.i_force, lay.i_torque, lay.law_states.start,
                    lay.forces.start, lay.lamella_count, lay.head], dtype=np.int64)
    consts = np.array([model._area, model._c2k, model._k_na, getattr(law, "gain", 0.0),
                       getattr(law, "coef", 0.0), 1.0 if model._film_on else 0.0,
                       model._film, model._temp])
    warm = law.warm_state()
    stuck = np.ones(lay.lamella_count, dtype=np.bool_) if warm is None else warm[0].copy()
    sigma = np.ones(lay.lamella_count) if warm is None else warm[1].astype(float)
    torque = np.empty(dts.size)
    work_before = model._work.copy()
    try:
        film, cur_temp = loop(ms, np.ascontiguousarray(inverse, dtype=np.int64),
                              np.ascontiguousarray(dts, dtype=float), press, omega, temp, sign,
                              model._work, idx, consts, fr, th, codes[0], codes[1], kmats,
                              nmats, gmats, hmats, stuck, sigma, states, forces, temps, films,
                              torque, law.records_forces)
    except _state["numba_error"] as err:  # compilation (typing/lowering) failed: nothing ran
        np.copyto(model._work, work_before)
        _disable(f"compilation failed ({type(err).__name__}: {str(err).splitlines()[0]})")
        if engine == "kernel":
            raise KernelUnavailableError(f"engine='kernel': {_state['reason']}") from err
        return None
    model._film, model._temp = float(film), float(cur_temp)
    if warm is not None:
        law.set_warm_state((stuck, sigma))
    return torque
