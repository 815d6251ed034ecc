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
    forces = np.zeros((n, lay.lamella_count))
    states = model._work[None, :lay.n_state].copy()
    if n > 1:
        load = mu * np.abs(sign)
        states = _loop(model, np.diff(t), press, load, forces)
        law = model.law
        if law.has_force and not law.records_forces:
            zn = states[:-1, lay.i_front]
            torque = np.where(zn > 0.0, model._c2k * load[1:] * zn, 0.0)
            forces[1:] = law.forces_series(states[:-1, lay.law_states],
                                           states[1:, lay.law_states], torque)
    return _outputs(params, model, t, press, omega, temp, mu, sign, states, forces)


def _loop(model, dts, press, load, forces):
    """Run steps 1..n-1; return the states (n, n_state) and fill ``forces[1:]`` if recorded.

    Row k of the work array ``wk`` is the pack's work vector of step k+1,
    ``[x_k, F_act, T, F_f]``: the step writes ``x_{k+1}`` straight into row k+1, so there is
    no copying per sample. T is written only where the discretisation uses it (ff_t); the
    other laws' matrices have an exactly zero T column. ``model`` ends in the same state
    as after the equivalent ``step()`` calls.
    """
    lay = model.layout
    work = model._work
    law = model.law
    nx, n = lay.n_state, press.size
    i_front, i_force, i_torque = lay.i_front, lay.i_force, lay.i_torque
    c2k, area = model._c2k, model._area
    dot = np.dot
    res = model.dt_resolution
    keys = np.maximum(np.rint(dts / res), 1.0).astype(np.int64) if res > 0.0 else dts
    if keys.min() == keys.max():  # uniform sampling: skip the sort
        uniq, inverse = keys[:1], np.zeros(keys.size, dtype=np.int64)
    else:
        uniq, inverse = np.unique(keys, return_inverse=True)
        inverse = inverse.reshape(-1)
    if res > 0.0:
        table = [model.discretisation(float(k) * res) for k in uniq.tolist()]
    else:
        table = [model.discretisation(float(d)) for d in uniq.tolist()]
    entries = [table[i] for i in inverse.tolist()]
    uses_torque = any(bool(e.M[:, i_torque].any()) for e in table)
    wk = np.zeros((n, lay.size))
    wk[0] = work
    wk[:-1, i_force] = np.where(press[1:] > 0.0, press[1:] * area, 0.0)
    lds = load[1:].tolist()
    heads, nexts = wk[:-1], wk[1:, :nx]
    if not law.acts_per_step:  # none, ff_t: nothing to do between steps
        if uses_torque:
            for entry, ld, r, o in zip(entries, lds, heads, nexts):
                zn = r.item(i_front)
                r[i_torque] = c2k * ld * zn if zn > 0.0 else 0.0
                dot(entry.M, r, out=o)
        else:
            for entry, r, o in zip(entries, heads, nexts):
                dot(entry.M, r, out=o)
    elif law.name == "ff_v" and not uses_torque:  # ViscousLaw.apply inlined (same ops)
        gain, multiply = law.gain, np.multiply
        for entry, ld, r, s, f, o in zip(entries, lds, heads, wk[:-1, lay.law_states],
                                         wk[:-1, lay.forces], nexts):
            zn = r.item(i_front)
            multiply(s, gain * (c2k * ld * zn if zn > 0.0 else 0.0), out=f)
            dot(entry.M, r, out=o)
    elif law.name == "coulomb" and not uses_torque:
        _loop_coulomb(model, law, entries, table, inverse, load[1:], wk)
    else:
        for k, (entry, ld) in enumerate(zip(entries, lds)):
            _step_one(model, entry, ld, wk, k)
    if n > 1:  # leave the model as step() would: last state, last step's held inputs
        last = wk[n - 2]
        zn = last.item(i_front)
        if not uses_torque:
            last[i_torque] = c2k * lds[-1] * zn if zn > 0.0 else 0.0
        work[nx:] = last[nx:]
        work[:nx] = wk[n - 1, :nx]
        if law.records_forces:
            forces[1:] = wk[:-1, lay.forces]
    return wk[:, :nx]


def _step_one(model, entry, ld, wk, k):
    """Step k+1 the way step() does it, on the model's work vector; row k gets its inputs."""
    lay = model.layout
    work = model._work
    nx = lay.n_state
    work[:lay.i_force] = wk[k, :lay.i_force]
    zn = work.item(lay.i_front)
    torque = model._c2k * ld * zn if zn > 0.0 else 0.0
    work[lay.i_force] = wk.item(k, lay.i_force)
    work[lay.i_torque] = torque
    model.law.apply(entry, torque, ld)
    np.dot(entry.M, work, out=wk[k + 1, :nx])
    wk[k, nx:] = work[nx:]


#: longest Coulomb block; keeps its checks' matrix products below OpenBLAS's threading size
#: (threads only add contention on a loaded machine)
_MAX_BLOCK = 512


def _loop_coulomb(model, law, entries, table, inverse, load, wk):
    """Coulomb law: whole stretches of an unchanged active set at once.

    Per sample :meth:`CoulombLaw.apply` checks that the active set of the previous step
    still holds (and then uses its forces) or re-solves. While the set is all sliding, the
    step map is affine in the state with the factor ``a`` (known per sample), so a block of
    samples is advanced with the set's fused kernel (:meth:`CoulombLaw.block_kernel`, one
    per dt), then its conditions are checked for the whole block at once, exactly as
    ``apply`` would check them sample by sample. The first step where they fail (or a = 0)
    is done by ``apply`` itself (re-solve, new set) and the next block starts after it. Sets
    with stuck lamellas go through ``apply`` step by step: their forces cancel large terms,
    so only the same operations reproduce them to 1e-9. Results equal the step loop to
    rounding.
    """
    lay = model.layout
    nx, head = lay.n_state, lay.head
    steps = len(entries)
    avec = law.coef * load
    tol = -1e-9 * (wk[:steps, lay.i_force] + 1.0)
    mix = np.ones((steps, 2))
    mix[:, 1] = avec
    lds = load.tolist()
    y = np.empty(2 * nx)
    y2 = y.reshape(2, nx)
    dot = np.dot
    fsl = lay.forces
    k, length, last_fast = 0, 4, False
    while k < steps:
        kend = min(k + length, steps)
        if kend - k < 2 or avec[k] <= 0.0 or law._stuck.any():
            _step_one(model, entries[k], lds[k], wk, k)
            k, length, last_fast = k + 1, 4, False
            continue
        blk = inverse[k:kend]
        which = blk[:1] if blk.min() == blk.max() else np.unique(blk)
        kerns = {i: law.block_kernel(table[i]) for i in which.tolist()}
        a_blk = avec[k:kend]
        rows_in, rows_out = wk[k:kend], wk[k + 1:kend + 1, :nx]
        if a_blk.min() == a_blk.max():  # a held (constant μ): one fused matrix per dt
            fused = {i: kern[0][:nx] + a_blk[0] * kern[0][nx:] for i, kern in kerns.items()}
            if len(fused) == 1:
                zc = fused[which.item(0)]
                for r, o in zip(rows_in, rows_out):
                    dot(zc, r, out=o)
            else:
                for i, r, o in zip(blk.tolist(), rows_in, rows_out):
                    dot(fused[i], r, out=o)
        elif len(kerns) == 1:
            zs = kerns[which.item(0)][0]
            for r, m, o in zip(rows_in, mix[k:kend], rows_out):
                dot(zs, r, out=y)
                dot(m, y2, out=o)
        else:
            for i, r, m, o in zip(blk.tolist(), rows_in, mix[k:kend], rows_out):
                dot(kerns[i][0], r, out=y)
                dot(m, y2, out=o)
        rows = wk[k:kend, :head]
        a = avec[k:kend, None]
        worst = np.empty(kend - k)
        for i, (_, pc, qc, _, _) in kerns.items():
            sel = slice(None) if len(kerns) == 1 else blk == i
            worst[sel] = (rows[sel] @ pc.T + a[sel] * (rows[sel] @ qc.T)).min(axis=1)
        ok = (worst >= tol[k:kend]) & (a_blk > 0.0)
        good = kend - k if ok.all() else int(np.argmin(ok))
        if good:
            rows, a, blk = rows[:good], a[:good], blk[:good]
            for i, (_, _, _, pf, qf) in kerns.items():
                sel = slice(None) if len(kerns) == 1 else blk == i
                wk[k:k + good, fsl][sel] = rows[sel] @ pf.T + a[sel] * (rows[sel] @ qf.T)
            law.iterations = 0
            last_fast = True
        if k + good == kend:  # the whole block held: try a longer one
            k, length = kend, min(2 * length, _MAX_BLOCK)
        else:  # the set fails at step k + good: apply() re-solves it
            k += good
            _step_one(model, entries[k], lds[k], wk, k)
            k, length, last_fast = k + 1, 4, False
    if last_fast:
        law._mats_entry = None


def _outputs(params, model, t, press, omega, temp, mu, sign, states, forces):
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
