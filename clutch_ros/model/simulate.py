"""Batch simulation of the pack over whole time series, identical to looping ``step()``.

``simulate(params, t, p, ω, T)``: the state at ``t[0]`` is the static equilibrium under
``initial_pressure`` (default ``p[0]``) with no spline force, and sample 0 reports it (like
:meth:`PackModel.reset` followed by :meth:`PackModel.output`); every later sample k is
``step(t[k] − t[k−1], p[k], ω[k], T[k])``. The per-sample loop performs the same operations as
``step()`` (same discretisation cache, same law code); only the outputs are computed
vectorised afterwards, so results equal the step loop to rounding.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clutch_ros.model.errors import DuplicateSample, InputError, NonFiniteSample, OutOfOrderSample
from clutch_ros.model.friction import friction_coefficient
from clutch_ros.model.pack import PackModel

__all__ = ["simulate", "SimulationResult", "as_series"]


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

    def __len__(self) -> int:
        return int(self.t.size)


def as_series(t, *values, names=("actuating_pressure", "slip_speed", "lamella_temperature")):
    """Validate stamps and broadcast inputs; return float arrays (t, *values).

    ``t`` must be 1-D, finite and strictly increasing; values broadcast to its shape and must
    be finite. Raises NonFiniteSample / OutOfOrderSample / DuplicateSample / InputError.
    """
    t = np.asarray(t, dtype=float)
    if t.ndim != 1 or t.size == 0:
        raise InputError(f"t must be a non-empty 1-D array, got shape {t.shape}")
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
        if not np.isfinite(arr).all():
            raise NonFiniteSample(f"{name}[{int(np.flatnonzero(~np.isfinite(arr))[0])}] is "
                                  "not finite")
        out.append(arr)
    return tuple(out)


def simulate(params, t, actuating_pressure, slip_speed, lamella_temperature,
             initial_pressure: float | None = None, *, model: PackModel | None = None
             ) -> SimulationResult:
    """Simulate the pack over stamps ``t`` [s] (module docstring); return the outputs.

    ``actuating_pressure`` [Pa], ``slip_speed`` [rad/s] and ``lamella_temperature`` [°C]
    are arrays of t's shape or scalars. ``model`` (optional) is used instead of a fresh
    :class:`PackModel` (its dt cache is reused; its state is reset and left at the end).
    """
    t, press, omega, temp = as_series(t, actuating_pressure, slip_speed, lamella_temperature)
    if model is None:
        model = PackModel(params)
    elif model.params != params:
        model.set_params(params)
    p0 = press[0] if initial_pressure is None else float(initial_pressure)
    model.reset(p0, temp[0], omega[0])
    lay = model.layout
    n = t.size
    mu = np.asarray(friction_coefficient(params, temp, press, omega), dtype=float)
    sign = np.tanh(omega / params.friction.sign_speed)
    states = np.empty((n, lay.n_state))
    forces = np.zeros((n, lay.lamella_count))
    work = model._work
    states[0] = work[:lay.n_state]
    if n > 1:
        load = mu * np.abs(sign)
        _loop(model, np.diff(t), press, load, states, forces)
        law = model.law
        if law.has_force and not law.records_forces:
            zn = states[:-1, lay.i_front]
            torque = np.where(zn > 0.0, model._c2k * load[1:] * zn, 0.0)
            forces[1:] = law.forces_series(states[:-1, lay.law_states],
                                           states[1:, lay.law_states], torque)
    return _outputs(params, model, t, press, omega, temp, mu, sign, states, forces)


def _loop(model, dts, press, load, states, forces):
    lay = model.layout
    work = model._work
    xview = model._xview
    fview = work[lay.forces]
    law = model.law
    apply = law.apply
    record = law.records_forces
    i_front, i_force, i_torque = lay.i_front, lay.i_force, lay.i_torque
    c2k, area = model._c2k, model._area
    dot = np.dot
    res = model.dt_resolution
    if res > 0.0:
        keys = np.maximum(np.rint(dts / res), 1.0).astype(np.int64)
        uniq, inverse = np.unique(keys, return_inverse=True)
        table = [model.discretisation(float(k) * res) for k in uniq.tolist()]
    else:
        uniq, inverse = np.unique(dts, return_inverse=True)
        table = [model.discretisation(float(d)) for d in uniq.tolist()]
    entries = [table[i] for i in inverse.tolist()]
    item = work.item
    rows = zip(entries, load[1:], press[1:], states[1:])
    if law.name == "ff_v":  # ViscousLaw.apply inlined (same operations)
        sview, gain, multiply = work[lay.law_states], law.gain, np.multiply
        for entry, ld, p, row in rows:
            zn = item(i_front)
            torque = c2k * ld * zn if zn > 0.0 else 0.0
            work[i_force] = p * area if p > 0.0 else 0.0
            work[i_torque] = torque
            multiply(sview, gain * torque, out=fview)
            dot(entry.M, work, out=row)
            xview[:] = row
    elif law.acts_per_step:
        for (entry, ld, p, row), k in zip(rows, range(1, len(entries) + 1)):
            zn = item(i_front)
            torque = c2k * ld * zn if zn > 0.0 else 0.0
            work[i_force] = p * area if p > 0.0 else 0.0
            work[i_torque] = torque
            apply(entry, torque, ld)
            dot(entry.M, work, out=row)
            xview[:] = row
            if record:
                forces[k] = fview
    else:  # none, ff_t: nothing to do between steps
        for entry, ld, p, row in rows:
            zn = item(i_front)
            work[i_force] = p * area if p > 0.0 else 0.0
            work[i_torque] = c2k * ld * zn if zn > 0.0 else 0.0
            dot(entry.M, work, out=row)
            xview[:] = row


def _outputs(params, model, t, press, omega, temp, mu, sign, states, forces):
    lay = model.layout
    n_lam = lay.lamella_count
    area = model._area
    pos = states[:, 0:lay.n_pack:2]
    normal = states[:, :lay.n_pack] @ model._spring.T
    zn = states[:, lay.i_front]
    torque = model._c2k * mu * np.maximum(zn, 0.0) * sign
    force = np.maximum(press, 0.0) * area
    ref = model._c2n * mu * force * sign
    front = normal[:, -1] / area
    rear = normal[:, 0] / area
    return SimulationResult(
        t=t, actuating_pressure=press, slip_speed=omega, lamella_temperature=temp,
        torque=torque, reference_torque=ref, mu=mu, normal_force=normal,
        spline_force=forces[:, :n_lam], front_pressure=front, rear_pressure=rear,
        pressure_difference=front - rear, compression=zn, positions=pos,
        velocities=states[:, 1:lay.n_pack:2].copy(), law=model.law.name)
