"""Compiled per-sample loop of the pack model (numba), used by :func:`simulate` when available.

:func:`~clutch_ros.model.simulate.simulate` (and so replay, fit and
:func:`~clutch_ros.model.batch.estimate_batch`) runs its per-sample loop here with
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
  warm-started active-set iteration with projected Gauss-Seidel as fallback
  (:mod:`clutch_ros.model.kernel_box`). The solution of the box problem is unique, so the
  compiled and the numpy solver agree to rounding (the products are summed in a different
  order, the stuck subsystem is solved by an in-place elimination instead of LAPACK;
  tests/model/test_kernel.py states the tolerances it checks).

Speed: nothing is allocated per sample (scratch arrays once per series); the ZOH matrices
(and the box laws' stick and normal matrices) are passed transposed, so ``x = M w`` runs
column by column over contiguous rows (vectorised by LLVM, each element still summed in the
order of the reference); no fastmath. :func:`run_columns` computes the outputs of every
sample inside the loop and keeps no state history (the estimator's batch path and the fit);
:func:`run_loop` records the states as :func:`~clutch_ros.model.simulate.simulate` needs.

The scalar helpers ``_mu``, ``_film_step``, ``_thermal_step`` and ``_sign`` restate, for one
sample, the formulas of :mod:`~clutch_ros.model.friction`, :mod:`~clutch_ros.model.film` and
the thermal model on purpose: numba checks a cached function against its own file only, so a
compiled function inlined from another module would keep running its old version after that
module changed. The copies live here, and the field-by-field tests against the numpy path
(tests/model/test_kernel.py) catch any drift.

Compiled code is cached on disk (``cache=True``) in ``NUMBA_CACHE_DIR`` (default: a
``numba/<digest of kernel_box.py>`` folder in the user cache dir, ``$XDG_CACHE_HOME`` or
``~/.cache``, under ``clutch_ros``), so only the first call after install pays the few
seconds of compilation.

Fallback, never silent: with ``engine="auto"``, if numba cannot be imported, compilation
fails, or ``CLUTCH_KERNEL=0`` is set, the numpy path runs, the reason is logged (a warning,
once per process; info for the explicit switch) and kept in :func:`unavailable_reason`.
``engine="kernel"`` raises :class:`KernelUnavailableError` instead of falling back.
"""

from __future__ import annotations

import hashlib
import logging
import math
import os
import threading
from collections import namedtuple
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from clutch_ros.model import kernel_box
from clutch_ros.model.errors import InputError, KernelUnavailableError
from clutch_ros.model.laws import LawTable, law_info
from clutch_ros.model.slip import lowpass_series as _lowpass_numpy

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from clutch_ros.model.arraytypes import FloatArray
    from clutch_ros.model.pack import PackModel

__all__ = ["ENGINES", "Columns", "History", "KernelUnavailableError", "LAW_CODES",
           "OUTPUT_COLUMNS", "Series", "available", "check_engine", "lowpass_series",
           "run_columns", "run_loop", "unavailable_reason"]

_log = logging.getLogger(__name__)

#: rows of :func:`run_columns`' output array: torque and Eq. 1 reference [N m], μ [-],
#: front and rear pressure [Pa], compression z_N [m], temperature [°C], film [-], spline
#: correction [Pa]
OUTPUT_COLUMNS = ("torque", "reference_torque", "mu", "front_pressure", "rear_pressure",
                  "compression", "lamella_temperature", "film", "spline_correction")

#: accepted values of simulate()'s ``engine`` argument
ENGINES = ("auto", "kernel", "numpy")

_VISCOUS, _BOX = kernel_box.VISCOUS, kernel_box.BOX
# replaced by the compiled functions in _compiled()
_box_apply, _mat_vec = kernel_box._box_apply, kernel_box.mat_vec
#: law name -> (kind, box variant) of the compiled loop (a live view of the registry's
#: :attr:`~clutch_ros.model.laws.SplineLawInfo.kernel`; laws without code are left out)
LAW_CODES = LawTable("kernel", where="kernel")

#: One series of steps: the discretisation entries (``model.discretisation``), the entry of
#: each step (n - 1,), the steps [s] (n - 1,), pressure [Pa], slip [rad/s], temperature
#: [°C] (NaN: not measured) and the torque sign (n,; size 0: computed in the loop).
Series = namedtuple("Series", "table inverse dts press omega temp sign")
#: :func:`~clutch_ros.model.simulate.simulate`'s state history, rows 1..n-1 written: states
#: (n, n_state), held spline forces (n, N) [N], temperature [°C] and film (n,).
History = namedtuple("History", "states forces temps films")
#: :func:`run_columns`' outputs: ``outs`` (9, offset + n) (:data:`OUTPUT_COLUMNS`), and
#: optionally ``normal`` / ``forces`` (offset + n, N) [N], written from column/row ``offset``.
Columns = namedtuple("Columns", "outs normal forces offset", defaults=(None, None, 0))

# The compiled loop's records (numba types namedtuples of arrays and scalars like tuples):
# per-dt matrices (ZOH transposed, entry per step, dts, the box laws' matrices); inputs;
# the model (work vector, its indices, constants, friction and thermal parameters, law
# codes, warm active set); what the loop writes (arrays with fewer rows than samples are not
# written, see _loop).
_Steps = namedtuple("_Steps", "mts inv dts box")
_Inputs = namedtuple("_Inputs", "press omega temp sign")
_Model = namedtuple("_Model", "work idx consts fr th law variant stuck sigma")
_Record = namedtuple("_Record", "states forces temps films torque outs normal offset")

#: loop: the compiled loop once numba is imported; reason: why the kernel cannot be used
_state: dict[str, Any] = {"loop": None, "reason": None, "numba_error": None}
#: the compiled _loop: (steps, inputs, model, record) -> (film, temperature)
_LoopFunction = Callable[..., tuple[float, float]]
_LOCK = threading.RLock()


def _cache_dir() -> str:
    """Default cache folder, one per version of kernel_box.py.

    numba checks a cached function against its own file only: a change in kernel_box.py alone
    would leave the cached loop of this file calling the old box code.
    """
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    digest = hashlib.sha1(Path(kernel_box.__file__).read_bytes()).hexdigest()[:12]
    return str(Path(base) / "clutch_ros" / "numba" / digest)


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
    reason: str | None = _state["reason"]
    return reason


def _disable(reason: str, level: int = logging.WARNING) -> None:
    _state["loop"] = None
    _state["reason"] = reason
    _log.log(level, "model kernel: %s; numpy path", reason)


def _compiled() -> _LoopFunction | None:
    loop: _LoopFunction | None = _state["loop"]
    if loop is not None or _state["reason"] is not None:
        return loop
    with _LOCK:  # threads (a fit's Jacobian, a replay's estimate) may ask at once: set up once
        return _set_up()


def _set_up() -> _LoopFunction | None:
    loop: _LoopFunction | None = _state["loop"]
    if loop is not None or _state["reason"] is not None:
        return loop
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
    # the per-step box functions are inlined at numba IR level (each call passes a dozen
    # arrays: ~30 % of an ff_t step otherwise); the rare solvers stay calls
    inline = numba.njit(cache=True, nogil=True, inline="always")
    for name in kernel_box.BOX_FUNCTIONS:  # compiled where they live (their globals)
        func = getattr(kernel_box, name)
        if not hasattr(func, "py_func"):
            rare = name in ("_lu_solve", "_gauss_seidel")
            setattr(kernel_box, name, (jit if rare else inline)(func))
    g["_box_apply"], g["_mat_vec"] = kernel_box._box_apply, kernel_box.mat_vec
    for name in ("_mu", "_film_step", "_thermal_step", "_sign", "_emit", "_loop"):
        func = g[name]  # helpers first: later functions call the compiled ones
        g[name] = func if hasattr(func, "py_func") else jit(func)
    loop = _state["loop"] = g["_loop"]
    return loop


# -- the per-sample code (plain Python; compiled by _compiled()) ------------------------------
# fr: mu_ref, temperature_slope, temperature_ref, pressure_loss_at_ref, pressure_ref,
#     stribeck_speed, static_ratio, film_depth, mu_min, film_thinning_time, film_recovery_time
# th: heat_capacity, conductance, oil_temperature


def _mu(fr: FloatArray, temperature: float, pressure: float, slip_speed: float,
        film: float) -> float:
    f_t = 1.0 + fr[1] * (temperature - fr[2])
    p = pressure if pressure > 0.0 else 0.0
    f_p = 1.0 - fr[3] * p / fr[4]
    x = slip_speed / fr[5]
    g = math.exp(-(x * x))
    f_w = 1.0 + (fr[6] - 1.0) * (g + (1.0 - g) * fr[7] * (1.0 - film))
    mu: float = fr[0] * f_t * f_p * f_w
    mu_min: float = fr[8]
    return mu if mu > mu_min else mu_min


def _film_step(fr: FloatArray, film: float, dt: float, pressure: float,
               slip_speed: float) -> float:
    x = slip_speed / fr[5]
    g = math.exp(-(x * x))
    p = pressure if pressure > 0.0 else 0.0
    thin: float = (p / fr[4]) * g / fr[9]
    rec: float = (1.0 - g) / fr[10]
    rate = thin + rec
    if rate <= 0.0:
        return film
    target = rec / rate
    return target + (film - target) * math.exp(-rate * dt)


def _thermal_step(th: FloatArray, temperature: float, dt: float, power: float) -> float:
    g: float = th[1]
    target: float = th[2] + power / g
    return target + (temperature - target) * math.exp(-dt * g / th[0])


def _sign(omega: float, sign_speed: float) -> float:
    """:func:`clutch_ros.model.friction.sign_factor` of one sample."""
    x = omega / sign_speed
    if x >= 1.0:
        return 1.0
    if x <= -1.0:
        return -1.0
    return 0.5 * x * (3.0 - x * x)


def _emit(k: int, o: int, mdl: _Model, inp: _Inputs, sg: float, temp_k: float, film_k: float,
          rec: _Record) -> None:
    """Write the outputs of sample ``k`` into column ``o`` of ``rec.outs`` (:data:`OUTPUT_COLUMNS`).

    The same formulas as :func:`clutch_ros.model.simulate.simulate`'s vectorised outputs;
    ``rec.normal`` (S_n) and ``rec.forces`` (F_fn) row ``o`` too when they have it.
    """
    work, fr, consts, idx = mdl.work, mdl.fr, mdl.consts, mdl.idx
    press, omega = inp.press, inp.omega
    outs, normal, forces = rec.outs, rec.normal, rec.forces
    i_front, f0, nlam = idx[1], idx[5], idx[6]
    area, c2k, k_na, c2n, stiff = consts[0], consts[1], consts[2], consts[8], consts[9]
    zn = work[i_front]
    zp = zn if zn > 0.0 else 0.0
    mu = _mu(fr, temp_k, zp * k_na, omega[k], film_k)
    mu_ref = _mu(fr, temp_k, press[k], omega[k], 1.0)
    force = press[k] * area if press[k] > 0.0 else 0.0
    outs[0, o] = c2k * mu * zp * sg
    outs[1, o] = c2n * mu_ref * force * sg
    outs[2, o] = mu
    front = work[2 * nlam - 2] * stiff
    if nlam > 1:
        front -= work[2 * nlam - 4] * stiff
    outs[3, o] = front / area
    outs[4, o] = work[0] * stiff / area
    outs[5, o] = zn
    outs[6, o] = temp_k
    outs[7, o] = film_k
    acc = 0.0
    for i in range(nlam):
        acc += work[f0 + i] * (i + 1.0)
    outs[8, o] = acc / (nlam * area)
    if normal.shape[0] > o:
        prev = 0.0
        for i in range(nlam):
            s = work[2 * i] * stiff
            normal[o, i] = s - prev
            prev = s
    if forces.shape[0] > o:
        for i in range(nlam):
            forces[o, i] = work[f0 + i]


def _loop(steps: _Steps, inp: _Inputs, mdl: _Model, rec: _Record) -> tuple[float, float]:
    """Run steps 1..n-1 of simulate() (PackModel._advance per sample); return (film, temp).

    ``steps.mts``: the ZOH matrices transposed (size, n_state) per dt entry. Arrays of
    ``rec`` with fewer rows than samples are not written: ``states``, ``forces`` (n, N),
    ``temps``, ``films``, ``torque`` (n - 1); ``outs`` (9, offset + n), columns
    ``offset + k`` (sample 0 too), and ``normal`` (offset + n, N) rows, ``forces`` too when
    ``outs`` is written. ``inp.sign`` of size 0: the sign is computed here from
    ``consts[10]`` (sign speed). The warm active set ``mdl.stuck``, ``mdl.sigma`` is updated.
    """
    mts, inv, dts = steps.mts, steps.inv, steps.dts
    press, omega, temp, sign = inp.press, inp.omega, inp.temp, inp.sign
    work, idx, consts, fr, th = mdl.work, mdl.idx, mdl.consts, mdl.fr, mdl.th
    law, stuck, sigma = mdl.law, mdl.stuck, mdl.sigma
    states, forces, temps, films = rec.states, rec.forces, rec.temps, rec.films
    torque_out, outs, offset = rec.torque, rec.outs, rec.offset
    nx, i_front, i_force, i_torque, s0, f0, nlam, head = (idx[0], idx[1], idx[2], idx[3],
                                                          idx[4], idx[5], idx[6], idx[7])
    area, c2k, k_na, gain, coef, film_on = (consts[0], consts[1], consts[2], consts[3],
                                            consts[4], consts[5])
    film = consts[6]
    cur_temp = consts[7]
    size = work.size
    n = press.size
    x = np.empty((1, nx))
    row = work.reshape(1, size)  # the work vector as a row, for mat_vec
    fs = np.zeros((kernel_box.SCRATCH_ROWS, nlam + 1))
    bb = np.zeros((4, nlam), dtype=np.bool_)
    ib = np.zeros((2, nlam), dtype=np.int64)
    gss = np.empty((nlam, nlam))
    for i in range(nlam):  # the warm active set
        bb[kernel_box.STUCK, i] = stuck[i]
        fs[kernel_box.SIGMA, i] = sigma[i]
    scratch = (fs, bb, ib, gss)
    lay = (head, s0, f0, nlam)
    has_sign = sign.size == n
    emit = outs.shape[1] >= offset + n
    if emit and n > 0:
        sg = sign[0] if has_sign else _sign(omega[0], consts[10])
        _emit(0, offset, mdl, inp, sg, cur_temp, film, rec)
    for k in range(1, n):
        j = k - 1
        sg = sign[k] if has_sign else _sign(omega[k], consts[10])
        t_in = temp[k]
        t_use = t_in if t_in == t_in else cur_temp
        zn = work[i_front]
        p_eq = zn * k_na if zn > 0.0 else 0.0
        mu = _mu(fr, t_use, p_eq, omega[k], film)
        load = mu * abs(sg)
        torque = c2k * load * zn if zn > 0.0 else 0.0
        work[i_force] = press[k] * area if press[k] > 0.0 else 0.0
        work[i_torque] = torque
        e = inv[j]
        if law == _VISCOUS:
            gt = gain * torque
            for i in range(nlam):
                work[f0 + i] = work[s0 + i] * gt
        elif law == _BOX:
            _box_apply(mdl.variant, row, lay, torque, coef * load, gain, steps.box, e, scratch)
        _mat_vec(mts, e, row, 0, size, nx, x, 0)  # x = M w
        for r in range(nx):
            work[r] = x[0, r]
        if film_on > 0.0:
            film = _film_step(fr, film, dts[j], p_eq, omega[k])
        if t_in == t_in:
            cur_temp = t_in
        else:
            cur_temp = _thermal_step(th, t_use, dts[j], torque * abs(omega[k]))
        if states.shape[0] == n:
            states[k] = x[0]
        if temps.size == n:
            temps[k] = cur_temp
            films[k] = film
        if torque_out.size == n - 1:
            torque_out[j] = torque
        if emit:
            _emit(k, offset + k, mdl, inp, sg, cur_temp, film, rec)
        elif forces.shape[0] == n:
            for i in range(nlam):
                forces[k, i] = work[f0 + i]
    for i in range(nlam):
        stuck[i] = bb[kernel_box.STUCK, i]
        sigma[i] = fs[kernel_box.SIGMA, i]
    return film, cur_temp


def _lowpass(dts: FloatArray, u: FloatArray, tau: float, out: FloatArray) -> None:
    """:func:`clutch_ros.model.slip.lowpass_series`'s loop (same float operations)."""
    y = u[0]
    out[0] = y
    for k in range(1, u.size):
        y = y + (-math.expm1(-dts[k - 1] / tau)) * (u[k] - y)
        out[k] = y


# -- the Python side -------------------------------------------------------------------------
def lowpass_series(t: ArrayLike, u: ArrayLike, time_constant: float,
                   engine: str = "auto") -> FloatArray:
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


def _box_matrices(law: Any, kind: int, table: Sequence[Any]) -> tuple[FloatArray, ...]:
    """Stacked per-dt matrices of the box laws: stick and normal transposed, G, Gᵀ, H."""
    if kind != _BOX:
        empty = np.zeros((len(table), 1, 1))
        return empty, empty, empty, empty, empty
    stick, normal, g, h = zip(*(law.box_matrices(e) for e in table))
    return (np.ascontiguousarray(np.transpose(stick, (0, 2, 1))),
            np.ascontiguousarray(np.transpose(normal, (0, 2, 1))),
            np.ascontiguousarray(g), np.ascontiguousarray(np.transpose(g, (0, 2, 1))),
            np.ascontiguousarray(h))


def _run(model: PackModel, series: Series, rec: _Record, engine: str) -> bool:
    """Call the compiled loop (see :func:`run_loop`); False when the numpy path must run.

    ``series``: :data:`Series`; ``rec``: the loop's outputs (``_Record``).
    """
    if check_engine(engine) == "numpy":
        return False
    law = model.law
    codes = law_info(law.name).kernel
    loop = _compiled()
    if loop is None or codes is None:
        why = _state["reason"] if loop is None else f"no compiled code for law {law.name!r}"
        if engine == "kernel":
            raise KernelUnavailableError(f"engine='kernel': {why}")
        if codes is None:
            _log.warning("model kernel: %s; numpy path", why)
        return False
    table = series.table
    steps = _Steps(np.ascontiguousarray(np.transpose([e.M for e in table], (0, 2, 1))),
                   np.ascontiguousarray(series.inverse, dtype=np.int64),
                   np.ascontiguousarray(series.dts, dtype=float),
                   _box_matrices(law, codes[0], table))
    mdl = _model_record(model, codes)
    work_before = model._work.copy()
    try:
        film, cur_temp = loop(steps, _Inputs(series.press, series.omega, series.temp,
                                             series.sign), mdl, rec)
    except _state["numba_error"] as err:  # compilation (typing/lowering) failed: nothing ran
        np.copyto(model._work, work_before)
        _disable(f"compilation failed ({type(err).__name__}: {str(err).splitlines()[0]})")
        if engine == "kernel":
            raise KernelUnavailableError(f"engine='kernel': {_state['reason']}") from err
        return False
    model._film, model._temp = float(film), float(cur_temp)
    if law.warm_state() is not None:
        law.set_warm_state((mdl.stuck, mdl.sigma))
    return True


def _model_record(model: PackModel, codes: tuple[int, int]) -> _Model:
    """Return the loop's ``_Model`` of ``model``: work vector (shared), indices, constants."""
    law, lay = model.law, model.layout
    fr_p, th_p, pk = model._fr, model.params.thermal, model.params.pack
    fr = np.array([fr_p.mu_ref, fr_p.temperature_slope, fr_p.temperature_ref,
                   fr_p.pressure_loss_at_ref, fr_p.pressure_ref, fr_p.stribeck_speed,
                   fr_p.static_ratio, fr_p.film_depth, fr_p.mu_min, fr_p.film_thinning_time,
                   fr_p.film_recovery_time], dtype=float)
    th = np.array([th_p.heat_capacity, th_p.conductance, th_p.oil_temperature], dtype=float)
    idx = np.array([lay.n_state, lay.i_front, lay.i_force, lay.i_torque, lay.law_states.start,
                    lay.forces.start, lay.lamella_count, lay.head], dtype=np.int64)
    consts = np.array([model._area, model._c2k, model._k_na, getattr(law, "gain", 0.0),
                       getattr(law, "coef", 0.0), 1.0 if model._film_on else 0.0,
                       model._film, model._temp, model._c2n, pk.lamella_stiffness,
                       model._sign_speed])
    warm = law.warm_state()
    stuck = np.ones(lay.lamella_count, dtype=np.bool_) if warm is None else warm[0].copy()
    sigma = np.ones(lay.lamella_count) if warm is None else warm[1].astype(float)
    return _Model(model._work, idx, consts, fr, th, codes[0], codes[1], stuck, sigma)


def run_loop(model: PackModel, series: Series, history: History,
             engine: str = "auto") -> FloatArray | None:
    """Run :func:`~clutch_ros.model.simulate.simulate`'s steps 1..n-1 compiled.

    ``series``: :data:`Series`; ``history``: :data:`History`. Same effects as the numpy loop
    there (fills ``states[1:]``, ``forces[1:]``, ``temps[1:]``, ``films[1:]``; leaves
    ``model`` as the step loop does) and returns the law's torque per step [N m]. Returns
    None when the caller must run the numpy loop: ``engine="numpy"``, or ``"auto"`` with the
    kernel unavailable (the reason is logged, see the module docstring). ``engine="kernel"``
    raises :class:`KernelUnavailableError` instead.
    """
    torque = np.empty(series.dts.size)
    none = np.empty((0, 0))
    rec = _Record(history.states, history.forces, history.temps, history.films, torque, none,
                  none, 0)
    if _run(model, series, rec, engine):
        return torque
    return None


def run_columns(model: PackModel, series: Series, columns: Columns,
                engine: str = "auto") -> bool:
    """Run the whole series compiled, writing only the outputs (no state history).

    ``series``: :data:`Series` (its ``sign`` is not used: the sign is computed in the loop).
    ``columns``: :data:`Columns`; ``outs`` (9, offset + n): in columns ``offset:offset + n``
    the :data:`OUTPUT_COLUMNS` of every sample, sample 0 (the state ``model`` starts in)
    included, with the formulas of :func:`~clutch_ros.model.simulate.simulate`; ``normal``
    and ``forces`` (offset + n, N), if given: S_n [N] and the held spline forces F_fn [N]
    (laws that keep them in the work vector, i.e. whose class records its forces) in the
    same rows. Returns False when the numpy path must run (as :func:`run_loop` returns None).
    """
    none = np.empty((0, 0))
    rec = _Record(none, none if columns.forces is None else columns.forces, np.empty(0),
                  np.empty(0), np.empty(0), columns.outs,
                  none if columns.normal is None else columns.normal, int(columns.offset))
    return _run(model, series._replace(sign=np.empty(0)), rec, engine)
