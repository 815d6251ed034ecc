"""Compiled per-sample loop of the pack model (numba), used by :func:`simulate` when available.

:func:`~clutch_ros.model.simulate.simulate` (and so replay, fit and
:func:`~clutch_ros.model.batch.estimate_batch`) runs its per-sample loop here with
``engine="kernel"`` or ``"auto"`` (the default); the numpy path
(:meth:`~clutch_ros.model.pack.PackModel._advance`, one Python call per sample) stays the
reference (``engine="numpy"``) and the fallback. This module is the Python side: it compiles
the loop, chooses the engine and hands the loop its records. The per-sample code itself (the
same steps in the same order as :meth:`PackModel._advance`, every law's branch, the scalar
helpers) is :mod:`clutch_ros.model.kernel_loop`, with the box solver of
:mod:`clutch_ros.model.kernel_box`; the two paths agree to rounding
(tests/model/test_kernel.py states the tolerances it checks).

:func:`run_columns` computes the outputs of every sample inside the loop and keeps no state
history (the estimator's batch path and the fit); :func:`run_loop` records the states as
:func:`~clutch_ros.model.simulate.simulate` needs.

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
import os
import threading
from collections import namedtuple
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from clutch_ros.model import kernel_box, kernel_loop
from clutch_ros.model.errors import InputError, KernelUnavailableError
from clutch_ros.model.kernel_loop import Inputs, LoopModel, Record, Steps
from clutch_ros.model.laws import LawTable, law_info
from clutch_ros.model.slip import lowpass_series as _lowpass_numpy

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from clutch_ros.model.arraytypes import FloatArray
    from clutch_ros.model.pack import PackModel

__all__ = ["ENGINES", "Columns", "History", "KernelUnavailableError", "LAW_CODES",
           "OUTPUT_COLUMNS", "Series", "available", "check_engine", "lowpass_series",
           "numba_cache_dir", "run_columns", "run_loop", "unavailable_reason"]

_log = logging.getLogger(__name__)

#: rows of :func:`run_columns`' output array: torque and Eq. 1 reference [N m], μ [-],
#: front and rear pressure [Pa], compression z_N [m], temperature [°C], film [-], spline
#: correction [Pa]
OUTPUT_COLUMNS = ("torque", "reference_torque", "mu", "front_pressure", "rear_pressure",
                  "compression", "lamella_temperature", "film", "spline_correction")

#: accepted values of simulate()'s ``engine`` argument
ENGINES = ("auto", "kernel", "numpy")

_BOX = kernel_box.BOX
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

#: loop: the compiled loop once numba is imported; reason: why the kernel cannot be used
_state: dict[str, Any] = {"loop": None, "reason": None, "numba_error": None}
#: the compiled kernel_loop._loop: (steps, inputs, model, record) -> (film, temperature)
_LoopFunction = Callable[..., tuple[float, float]]
_LOCK = threading.RLock()


def numba_cache_dir() -> str:
    """Default numba cache folder of clutch_ros, one per version of kernel_box.py.

    numba checks a cached function against its own file only: a change in kernel_box.py alone
    would leave the cached loop of kernel_loop.py calling the old box code.
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
    os.environ.setdefault("NUMBA_CACHE_DIR", numba_cache_dir())
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
    # the per-step box functions are inlined at numba IR level (each call passes a dozen
    # arrays: ~30 % of an ff_t step otherwise); the rare solvers stay calls
    inline = numba.njit(cache=True, nogil=True, inline="always")
    for name in kernel_box.BOX_FUNCTIONS:  # compiled where they live (their globals)
        func = getattr(kernel_box, name)
        if not hasattr(func, "py_func"):
            rare = name in ("_lu_solve", "_gauss_seidel")
            setattr(kernel_box, name, (jit if rare else inline)(func))
    kernel_loop._box_apply, kernel_loop._mat_vec = kernel_box._box_apply, kernel_box.mat_vec
    for name in kernel_loop.LOOP_FUNCTIONS:  # compiled where they live (their globals)
        func = getattr(kernel_loop, name)
        if not hasattr(func, "py_func"):
            setattr(kernel_loop, name, jit(func))
    loop = _state["loop"] = kernel_loop._loop
    return loop


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
        kernel_loop._lowpass(np.diff(np.asarray(t, dtype=float)), np.ascontiguousarray(u), tau,
                             out)
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


def _run(model: PackModel, series: Series, rec: Record, engine: str) -> bool:
    """Call the compiled loop (see :func:`run_loop`); False when the numpy path must run.

    ``series``: :data:`Series`; ``rec``: the loop's outputs
    (:data:`~clutch_ros.model.kernel_loop.Record`).
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
    steps = Steps(np.ascontiguousarray(np.transpose([e.M for e in table], (0, 2, 1))),
                  np.ascontiguousarray(series.inverse, dtype=np.int64),
                  np.ascontiguousarray(series.dts, dtype=float),
                  _box_matrices(law, codes[0], table))
    mdl = _model_record(model, codes)
    work_before = model._work.copy()
    try:
        film, cur_temp = loop(steps, Inputs(series.press, series.omega, series.temp,
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


def _model_record(model: PackModel, codes: tuple[int, int]) -> LoopModel:
    """Return the loop's record of ``model``: work vector (shared), indices, constants.

    A :data:`~clutch_ros.model.kernel_loop.LoopModel`.
    """
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
    return LoopModel(model._work, idx, consts, fr, th, codes[0], codes[1], stuck, sigma)


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
    rec = Record(history.states, history.forces, history.temps, history.films, torque, none,
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
    rec = Record(none, none if columns.forces is None else columns.forces, np.empty(0),
                 np.empty(0), np.empty(0), columns.outs,
                 none if columns.normal is None else columns.normal, int(columns.offset))
    return _run(model, series._replace(sign=np.empty(0)), rec, engine)
