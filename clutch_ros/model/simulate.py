"""Batch simulation of the pack over whole time series, identical to looping ``step()``.

``simulate(params, t, p, ω, T)``: the state at ``t[0]`` is the static equilibrium under
``initial_pressure`` (default ``p[0]``) with no spline force, and sample 0 reports it (like
:meth:`PackModel.reset` followed by :meth:`PackModel.output`); every later sample k is
``step(t[k] − t[k−1], p[k], ω[k], T[k])``. The per-sample loop runs the very code ``step()``
runs (:meth:`PackModel._advance`: same discretisation cache, same law code, film and thermal
states); only the outputs are computed vectorised afterwards, so results equal the step loop to
rounding. (μ depends on the pack's state, so the whole-block fast paths of earlier versions,
which needed μ known in advance, are gone.)

Engines: ``engine="numpy"`` runs that loop (the reference); ``"kernel"`` runs the same steps
compiled (:mod:`clutch_ros.model.kernel`, numba; equal to the reference to rounding, see
tests/model/test_kernel.py) and raises if it cannot; ``"auto"`` (default) uses the kernel when
it is available and otherwise the numpy loop, logging why (the result says which ran).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from clutch_ros.model import kernel
from clutch_ros.model.errors import DuplicateSample, InputError, NonFiniteSample, OutOfOrderSample
from clutch_ros.model.friction import friction_coefficient, sign_factor
from clutch_ros.model.pack import PackModel

if TYPE_CHECKING:
    from numpy.typing import ArrayLike, NDArray

    from clutch_ros.model.arraytypes import FloatArray, IntArray
    from clutch_ros.model.discretisation import _Entry
    from clutch_ros.model.params import ClutchParams

__all__ = ["simulate", "simulate_columns", "SimulationResult", "as_series"]


@dataclass
class SimulationResult:
    """Pack outputs over a series of n samples (N lamellas).

    Attributes (shape (n,) unless noted):
        t: sample stamps [s]
        actuating_pressure: input [Pa]; slip_speed: input [rad/s];
        lamella_temperature: input [°C]
        torque: Eq. 27, signed like the slip [N m]
        reference_torque: Eq. 1, same μ and sign [N m]
        mu: friction coefficient [-]
        normal_force: (n, N) S_n rear → front [N]
        spline_force: (n, N) F_fn of the step ending at the sample [N] (as PackSample)
        front_pressure, rear_pressure, pressure_difference: S_N/A, S_1/A, their difference [Pa]
        compression: z_N [m]
        positions: (n, N) z_n [m]; velocities: (n, N) ż_n [m/s]
        law: spline law name
        engine: which loop ran, ``"kernel"`` or ``"numpy"`` (see the module docstring)

    """

    t: np.ndarray
    actuating_pressure: np.ndarray
    slip_speed: np.ndarray
    lamella_temperature: np.ndarray
    torque: np.ndarray
    reference_torque: np.ndarray
    mu: np.ndarray
    normal_force: np.ndarray
    spline_force: np.ndarray
    front_pressure: np.ndarray
    rear_pressure: np.ndarray
    pressure_difference: np.ndarray
    compression: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray
    law: str
    film: np.ndarray
    engine: str = "numpy"

    def __len__(self) -> int:
        return int(self.t.size)


def as_series(t: ArrayLike, *values: ArrayLike,
              names: tuple[str, ...] = ("actuating_pressure", "slip_speed",
                                        "lamella_temperature")) -> tuple[FloatArray, ...]:
    """Validate stamps and broadcast inputs; return float arrays (t, *values).

    ``t`` must be 1-D, finite and strictly increasing; values broadcast to its shape and must
    be finite (a lamella temperature may be NaN: not measured). Raises NonFiniteSample /
    OutOfOrderSample / DuplicateSample / InputError.
    """
    t = np.asarray(t, dtype=float)
    if t.ndim != 1 or t.size == 0:
        raise InputError(f"t must be a non-empty 1-D array, got shape {t.shape}")
    out: list[FloatArray]
    if not np.isfinite(t).all():
        raise NonFiniteSample(f"t[{int(np.flatnonzero(~np.isfinite(t))[0])}] is not finite")
    dts = np.diff(t)
    if (dts < 0).any():
        raise OutOfOrderSample(f"t decreases at index {int(np.flatnonzero(dts < 0)[0]) + 1}")
    if (dts == 0).any():
        raise DuplicateSample(f"t repeats at index {int(np.flatnonzero(dts == 0)[0]) + 1}")
    out = [t]
    for name, value in zip(names, values):
        try:
            arr = np.broadcast_to(np.asarray(value, dtype=float), t.shape).copy()
        except ValueError as err:
            raise InputError(f"{name} has shape {np.shape(value)}, t has {t.shape}") from err
        bad = np.isinf(arr) if name == "lamella_temperature" else ~np.isfinite(arr)
        if bad.any():
            raise NonFiniteSample(f"{name}[{int(np.flatnonzero(bad)[0])}] is "
                                  "not finite")
        out.append(arr)
    return tuple(out)


def simulate(params: ClutchParams, t: ArrayLike, actuating_pressure: ArrayLike,
             slip_speed: ArrayLike, lamella_temperature: ArrayLike,
             initial_pressure: float | None = None, *, model: PackModel | None = None,
             engine: str = "auto", reset: bool = True) -> SimulationResult:
    """Simulate the pack over stamps ``t`` [s] (module docstring); return the outputs.

    ``actuating_pressure`` [Pa], ``slip_speed`` [rad/s] and ``lamella_temperature`` [°C]
    are arrays of t's shape or scalars; a NaN temperature means "not measured" (the model's
    thermal state is used). ``model`` (optional) is used instead of a fresh
    :class:`PackModel` (its dt cache is reused; its state is reset and left at the end).
    ``engine``: ``"auto"`` | ``"kernel"`` | ``"numpy"`` (module docstring). ``reset`` False
    (with ``model``): no reset, sample 0 is the state ``model`` is in (a series continued
    from where the last one ended; its sample-0 spline force reads 0, ``initial_pressure`` is
    not used).
    """
    kernel.check_engine(engine)
    t, press, omega, temp = as_series(t, actuating_pressure, slip_speed, lamella_temperature)
    if model is None:
        model = PackModel(params)
    elif model.params != params:
        model.set_params(params)
    if reset:
        p0 = press[0] if initial_pressure is None else float(initial_pressure)
        model.reset(p0, temp[0], omega[0])
    lay = model.layout
    n = t.size
    sign = sign_factor(omega, params.friction.sign_speed)
    forces = np.zeros((n, lay.lamella_count))
    states = np.empty((n, lay.n_state))
    states[0] = model._work[:lay.n_state]
    temps = np.empty(n)
    films = np.empty(n)
    temps[0], films[0] = model._temp, model._film
    law = model.law
    ran = "numpy"
    if n > 1:
        series = kernel.Series(*_table(model, t), press, omega, temp, sign)
        torque, ran = _loop(model, series, kernel.History(states, forces, temps, films), engine)
        if law.has_force and not law.records_forces:
            forces[1:] = law.forces_series(states[:-1, lay.law_states],
                                           states[1:, lay.law_states], torque)
    result = _outputs(params, model, t, press, omega, temps, films, sign, states, forces)
    result.engine = ran
    return result


def _table(model: PackModel, t: FloatArray) -> tuple[list[_Entry], IntArray, FloatArray]:
    """Return the steps of ``t``: (discretisation entries, entry index per step, dts [s])."""
    dts = np.diff(t)
    if dts.size == 0:  # one sample: no step (an entry only to give the loop its shapes)
        return [model.discretisation(1e-3)], np.zeros(0, dtype=np.int64), dts
    res = model.dt_resolution
    # keys: dt in units of the resolution (int64), or the dts themselves
    keys: NDArray[Any] = np.maximum(np.rint(dts / res), 1.0).astype(np.int64) if res > 0.0 \
        else dts
    if keys.min() == keys.max():  # uniform sampling: one entry
        uniq, inverse = keys[:1], np.zeros(keys.size, dtype=np.int64)
    else:
        uniq, inverse = np.unique(keys, return_inverse=True)
        inverse = inverse.reshape(-1)
    if res > 0.0:
        table = [model.discretisation(float(k) * res) for k in uniq.tolist()]
    else:
        table = [model.discretisation(float(d)) for d in uniq.tolist()]
    return table, inverse, dts


def simulate_columns(params: ClutchParams, t: FloatArray, actuating_pressure: FloatArray,
                     slip_speed: FloatArray, lamella_temperature: FloatArray,
                     outs: FloatArray | kernel.Columns, *,
                     model: PackModel, engine: str = "auto", reset: bool = True) -> bool:
    """:func:`simulate`'s outputs written straight into arrays by the compiled kernel.

    For long series when only some outputs are needed: no state history, no per-lamella
    arrays unless asked. ``t`` [s] (validated, strictly increasing), pressure [Pa], slip
    [rad/s] and temperature [°C] are float64 arrays of one length n (NaN temperature: not
    measured); ``outs`` (9, ≥ n) receives :data:`~clutch_ros.model.kernel.OUTPUT_COLUMNS`
    in columns ``0:n``; or ``outs`` is a :data:`~clutch_ros.model.kernel.Columns`
    ``(outs, normal, forces, offset)``: ``outs`` (9, ≥ offset + n) receives them in columns
    ``offset:offset + n``, ``normal`` / ``forces`` (≥ offset + n, N), if not None, the
    normal [N] and spline forces [N] in rows ``offset:offset + n``. ``model`` is reset
    to the equilibrium at the first sample, as :func:`simulate` does (``reset`` False: it
    continues from the state it is in, which sample 0 reports). Returns False, having
    done nothing, when the kernel cannot run it (``engine="numpy"``, numba unavailable, or a
    law whose forces are not kept per step: ``ff_t_printed`` / ``ff_v_printed``); the caller
    then uses :func:`simulate`. Same results as :func:`simulate` to rounding
    (tests/model/test_kernel.py).
    """
    if kernel.check_engine(engine) == "numpy" or model.law.has_force and \
            not model.law.records_forces or not kernel.available():
        if engine == "kernel" and not kernel.available():
            raise kernel.KernelUnavailableError(f"engine='kernel': {kernel.unavailable_reason()}")
        return False
    if model.params != params:
        model.set_params(params)
    if reset:
        model.reset(float(actuating_pressure[0]), float(lamella_temperature[0]),
                    float(slip_speed[0]))
    columns = outs if isinstance(outs, kernel.Columns) else kernel.Columns(outs)
    series = kernel.Series(*_table(model, t), actuating_pressure, slip_speed,
                           lamella_temperature, np.empty(0))
    return kernel.run_columns(model, series, columns, engine)


def _loop(model: PackModel, series: kernel.Series, history: kernel.History,
          engine: str) -> tuple[FloatArray, str]:
    """Run steps 1..n-1 compiled or with :meth:`PackModel._advance` (the code ``step()`` runs).

    ``series``: :data:`~clutch_ros.model.kernel.Series`; fills the rows of ``history``
    (:data:`~clutch_ros.model.kernel.History`); returns (the law's torque per step, the engine
    that ran).
    """
    lay = model.layout
    nx = lay.n_state
    work = model._work
    law = model.law
    table, inverse, dts = series.table, series.inverse, series.dts
    press, omega, temp, sign = series.press, series.omega, series.temp, series.sign
    states, forces, temps, films = history
    torque = kernel.run_loop(model, series, history, engine)
    if torque is not None:
        return torque, "kernel"
    entries = [table[i] for i in inverse.tolist()]
    record = law.records_forces
    fview = work[lay.forces]
    advance = model._advance
    torque = np.empty(dts.size)
    for k, (entry, dt, p, w, tp, sg) in enumerate(zip(
            entries, dts.tolist(), press[1:].tolist(), omega[1:].tolist(),
            temp[1:].tolist(), sign[1:].tolist()), start=1):
        torque[k - 1] = advance(entry, dt, p, w, tp, sg)
        states[k] = work[:nx]
        if record:
            forces[k] = fview
        temps[k] = model._temp
        films[k] = model._film
    return torque, "numpy"


def _outputs(params: ClutchParams, model: PackModel, t: FloatArray, press: FloatArray,
             omega: FloatArray, temps: FloatArray, films: FloatArray, sign: FloatArray,
             states: FloatArray, forces: FloatArray) -> SimulationResult:
    lay = model.layout
    n_lam = lay.lamella_count
    area = model._area
    pos = states[:, 0:lay.n_pack:2]
    # S_n = k z_n − k z_{n−1} (spring_force_matrix) elementwise: the (n, 2N) @ (2N, N)
    # product would go to multi-threaded BLAS, slow when the cores are busy
    stiffness = model.params.pack.lamella_stiffness
    normal = pos * stiffness
    normal[:, 1:] -= pos[:, :-1] * stiffness
    zn = states[:, lay.i_front]
    p_eq = np.maximum(zn, 0.0) * model._k_na
    mu = np.asarray(friction_coefficient(params, temps, p_eq, omega, films), dtype=float)
    mu_ref = np.asarray(friction_coefficient(params, temps, press, omega), dtype=float)
    torque = model._c2k * mu * np.maximum(zn, 0.0) * sign
    force = np.maximum(press, 0.0) * area
    ref = model._c2n * mu_ref * force * sign
    front = normal[:, -1] / area
    rear = normal[:, 0] / area
    return SimulationResult(
        t=t, actuating_pressure=press, slip_speed=omega, lamella_temperature=temps,
        torque=torque, reference_torque=ref, mu=mu, normal_force=normal,
        spline_force=forces[:, :n_lam], front_pressure=front, rear_pressure=rear,
        pressure_difference=front - rear, compression=zn, positions=pos,
        velocities=states[:, 1:lay.n_pack:2].copy(), law=model.law.name, film=films)
