"""The per-sample code of the compiled pack loop: plain Python, compiled by :mod:`~.kernel`.

:mod:`clutch_ros.model.kernel` runs :func:`~clutch_ros.model.simulate.simulate`'s per-sample
loop here (``engine="kernel"`` or ``"auto"``). The loop performs the same steps in the same
order per sample as the numpy reference (thesis Eqs. 11-27,
:meth:`~clutch_ros.model.pack.PackModel._advance`): μ at the start of the step from the pack's
own state (normal-force pressure, film, temperature), the spline law's held forces, the exact
ZOH ``x⁺ = M w`` (M = [Φ | Γ] of the step's dt, built by the model's discretisation cache),
then the oil film and thermal states with the inputs held. Laws:

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
order of the reference); no fastmath. :func:`_loop` computes the outputs of every sample
(:func:`_emit`, :func:`~clutch_ros.model.kernel.run_columns`: no state history) or records
the states as :func:`~clutch_ros.model.simulate.simulate` needs
(:func:`~clutch_ros.model.kernel.run_loop`).

The scalar helpers ``_mu``, ``_film_step``, ``_thermal_step`` and ``_sign`` restate, for one
sample, the formulas of :mod:`~clutch_ros.model.friction`, :mod:`~clutch_ros.model.film` and
the thermal model on purpose: numba checks a cached function against its own file only, so a
compiled function inlined from another module would keep running its old version after that
module changed. The copies live here, in the loop's own file, and the field-by-field tests
against the numpy path (tests/model/test_kernel.py) catch any drift. (The box code of
:mod:`~clutch_ros.model.kernel_box` is the one exception: the kernel's cache folder is named
by its digest.)

This module does not import numba; :func:`clutch_ros.model.kernel._compiled` compiles its
functions in place (:data:`LOOP_FUNCTIONS`; they stay plain Python, and correct, without
numba).
"""

from __future__ import annotations

import math
from collections import namedtuple
from typing import TYPE_CHECKING

import numpy as np

from clutch_ros.model import kernel_box

if TYPE_CHECKING:
    from clutch_ros.model.arraytypes import FloatArray

__all__ = ["LOOP_FUNCTIONS", "Inputs", "LoopModel", "Record", "Steps"]

#: compiled in this order (helpers first: later functions call the compiled ones)
LOOP_FUNCTIONS = ("_mu", "_film_step", "_thermal_step", "_sign", "_emit", "_loop", "_lowpass")

_VISCOUS, _BOX = kernel_box.VISCOUS, kernel_box.BOX
# replaced by the compiled functions in kernel._compiled()
_box_apply, _mat_vec = kernel_box._box_apply, kernel_box.mat_vec

# The compiled loop's records (numba types namedtuples of arrays and scalars like tuples):
# per-dt matrices (ZOH transposed, entry per step, dts, the box laws' matrices); inputs;
# the model (work vector, its indices, constants, friction and thermal parameters, law
# codes, warm active set); what the loop writes (arrays with fewer rows than samples are not
# written, see _loop).
Steps = namedtuple("Steps", "mts inv dts box")
Inputs = namedtuple("Inputs", "press omega temp sign")
LoopModel = namedtuple("LoopModel", "work idx consts fr th law variant stuck sigma")
Record = namedtuple("Record", "states forces temps films torque outs normal offset")


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


def _emit(k: int, o: int, mdl: LoopModel, inp: Inputs, sg: float, temp_k: float,
          film_k: float, rec: Record) -> None:
    """Write the outputs of sample ``k`` into column ``o`` of ``rec.outs``.

    Rows :data:`~clutch_ros.model.kernel.OUTPUT_COLUMNS`, with the same formulas as
    :func:`clutch_ros.model.simulate.simulate`'s vectorised outputs;
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


def _loop(steps: Steps, inp: Inputs, mdl: LoopModel, rec: Record) -> tuple[float, float]:
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
