"""The N-lamella pack model (thesis 6.1-6.3, Eqs. 11-27) with a spline-friction law.

Units: time [s], pressure [Pa], force [N], displacement [m], torque [N m], slip speed
[rad/s], temperature [°C]. Arrays over lamellas are ordered rear (n = 1, at the housing
spring) → front (n = N, where F_act = p · A acts), as the thesis numbers them.

Sampling convention (the whole model core uses it): a sample's inputs are held over the
interval that *ends* at its stamp. ``step(dt, p, ω, T)`` advances the state by ``dt`` with
F_act = max(p, 0) · A held (exact zero-order hold: matrix exponential of the pack + law
system, so stable for any dt, however stiff the axial mode) and returns the outputs at the
new state. The spline forces are held too (every law but ``ff_t_printed``, whose force is
integrated with the pack). Negative pressures count as 0 (the piston cannot pull).

Friction coefficient: μ comes from the pack's own state, not the input pressure: the pressure
equivalent of the mean normal force ``Σ S_n / (N A) = k z_N / (N A)``, the oil-film state φ
(:mod:`clutch_ros.model.film`) and the lamella temperature. A NaN temperature means "not
measured": the model then integrates its thermal state from the dissipated power
``|T| · |ω|``; a measured temperature always wins. Film and thermal states advance once per
step with the step's inputs held, after the pack.

Outputs (:class:`PackSample`): normal force on lamella n ``S_n = k (z_n − z_{n−1})`` (the
spring behind it, z_0 = 0); torque by Eq. 27, ``2 μ R_e Σ S_n`` = ``2 μ R_e k z_N`` (the sum
telescopes), floored at 0 (contacts carry no tension) and signed by the regularised sign
``s(ω)`` (see :mod:`clutch_ros.model.friction`); the reference (Eq. 1) uses μ at the actuating
pressure with an intact film; front/rear pressure = S_N / A and S_1 / A, P_diff =
front − rear (thesis Fig. 20). The torque a spline law sees is the torque magnitude at the
start of the step (see :mod:`clutch_ros.model.spline`).

The discretisation is cached per dt: dt is quantised to ``dt_resolution`` (default 10 µs) and
the matrices are built for the quantised value, so a jittery 1 kHz stamp (±50 µs) re-uses ~10
entries. A new dt's ``e^{A dt}`` comes in closed form from the pack's modes
(:class:`~clutch_ros.model.discretisation.PackModes`, exact to rounding, ~80 µs) for the laws
whose states are decoupled from the pack (``none``, ``coulomb``, ``ff_t``), else from ``expm``
(~0.2-0.5 ms; ``transition="expm"`` forces it, the reference).
The error is ≤ 5 µs of hold time per step, random in sign, i.e. ≤ 5e-5 of the transient per
step for the 0.1 s pack time constant, and none at all at equilibrium (which is exact for every
dt). Dts below the resolution count as one resolution step; ``dt_resolution=0`` keys the
cache on the exact dt. Up to ``cache_size`` (256) dts are kept, the least recently used
evicted first (a rig's few common dts stay however many rare ones a burst brings).
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from clutch_ros.model.arraytypes import FloatArray
from clutch_ros.model.discretisation import PackModes, _Entry, _Layout
from clutch_ros.model.errors import InputError, NonFiniteSample
from clutch_ros.model.film import film_equilibrium, film_step, thermal_step
from clutch_ros.model.friction import mu_scalar, sign_scalar
from clutch_ros.model.laws import make_spline_law
from clutch_ros.model.statespace import (
    build_state_space,
    spring_force_matrix,
    static_gain,
    zoh_discretize,
)

if TYPE_CHECKING:
    from clutch_ros.model.params import ClutchParams, PackParams
    from clutch_ros.model.spline import SplineLaw, WarmState

__all__ = ["PackModel", "PackSample", "PackState", "TRANSITIONS"]

#: ways to compute e^{A dt} of a new dt (:class:`PackModel` ``transition``)
TRANSITIONS = ("auto", "expm")


@dataclass(slots=True)
class PackSample:
    """Outputs of the pack at one sample (scalars are floats; arrays have shape (N,)).

    Attributes:
        torque: modelled torque, Eq. 27, signed like the slip speed [N m]
        reference_torque: steady-state torque, Eq. 1, same μ and sign [N m]
        mu: friction coefficient used [-]
        normal_force: S_n on each lamella, rear → front [N]
        spline_force: spline friction force F_fn of the last step, rear → front [N] (the
            held value; ff_t: its value at the end of the step)
        front_pressure: S_N / A [Pa]
        rear_pressure: S_1 / A [Pa]
        pressure_difference: P_diff = front − rear [Pa]
        compression: z_N, displacement of the front lamella [m]
        lamella_temperature: temperature μ used, measured or the thermal state [°C]
        film: oil-film state φ after the step (1 = intact) [-]

    """

    torque: float
    reference_torque: float
    mu: float
    normal_force: np.ndarray
    spline_force: np.ndarray
    front_pressure: float
    rear_pressure: float
    pressure_difference: float
    compression: float
    lamella_temperature: float
    film: float


@dataclass(frozen=True)
class PackState:
    """Snapshot of a :class:`PackModel` (see :meth:`PackModel.restore`).

    ``work`` holds ``[z_1, ż_1, …, z_N, ż_N, law states, F_act, T, F_f1…F_fN]``; ``film``
    the oil-film state φ [-], ``temperature`` the thermal state [°C].
    """

    lamella_count: int
    law: str
    work: FloatArray
    warm: WarmState | None = None
    film: float = 1.0
    temperature: float = 35.0

    @property
    def positions(self) -> np.ndarray:
        """z_n rear → front [m]."""
        return self.work[0:2 * self.lamella_count:2].copy()

    @property
    def velocities(self) -> np.ndarray:
        """ż_n rear → front [m/s]."""
        return self.work[1:2 * self.lamella_count:2].copy()


class PackModel:
    """N-lamella pack with a spline-friction law; see the module docstring.

    Args:
        params: :class:`~clutch_ros.model.params.ClutchParams`.
        dt_resolution: quantisation of dt for the discretisation cache [s] (0 = exact dt).
        cache_size: number of dts kept.
        transition: how a new dt's ``e^{A dt}`` is computed: ``"auto"`` (default) in closed
            form (:class:`~clutch_ros.model.discretisation.PackModes`) where the law's states
            are decoupled from the pack (``none``, ``coulomb``, ``ff_t``), else by ``expm``;
            ``"expm"``: always by ``expm`` (the reference). The outputs agree with ``expm`` to
            ~1e-9 (tests/model/test_pack.py). That difference once flipped ``clutch fit --law
            auto --fit-compliance``'s coulomb fit to rank-deficient: its optimum sits where a
            break-away crosses a sample stamp, a jump of the residual that forward differences
            spiked depending on round-off; the fit's Jacobian now takes the one-sided slope
            there (:mod:`~clutch_ros.model.fd_jacobian`; tests/offline/test_fit_robust.py).

    """

    # discretisation cache: key (dt in units of dt_resolution, or dt itself) -> entry
    _cache: OrderedDict[float, _Entry]
    _last_key: float | None
    _last_entry: _Entry | None

    def __init__(self, params: ClutchParams, *, dt_resolution: float = 1e-5,
                 cache_size: int = 256, transition: str = "auto") -> None:
        if not (dt_resolution >= 0.0 and math.isfinite(dt_resolution)):
            raise InputError(f"dt_resolution must be finite and >= 0, got {dt_resolution!r}")
        if transition not in TRANSITIONS:
            raise InputError(f"transition must be one of {', '.join(TRANSITIONS)}, got "
                             f"{transition!r}")
        self.dt_resolution = float(dt_resolution)
        self.cache_size = max(1, int(cache_size))
        self.transition = transition
        self.misses = 0  # discretisations computed (cache misses), for diagnostics
        self._configure(params)
        self.reset()

    # -- construction -----------------------------------------------------------------
    def _configure(self, params: ClutchParams) -> None:
        old = self.__dict__.get("params")
        # the discretisation (and the law's per-dt matrices) depends on the pack and the
        # spline law only: new friction or thermal parameters (the adaptation's friction
        # scale, about once a second live) keep the cache instead of paying ~10 expm and
        # box set-ups (~0.3 ms each) on the next steps, a latency spike of several ms
        kept = (self._cache, self._last_key, self._last_entry) if (
            old is not None and old.pack == params.pack and old.spline == params.spline) \
            else None
        self.params = params
        pk = params.pack
        n = pk.lamella_count
        law: SplineLaw = make_spline_law(params)
        ns = law.n_states
        n_pack = 2 * n
        nx = n_pack + ns
        layout = _Layout(n, n_pack, nx, nx + 2, nx + 2 + n, slice(nx + 2, nx + 2 + n),
                         slice(n_pack, nx), nx, nx + 1, n_pack - 2)
        a, b = build_state_space(n, pk.lamella_mass, pk.lamella_stiffness, pk.lamella_damping)
        x_ss = static_gain(n, pk.lamella_stiffness)
        a_full = np.zeros((nx, nx))
        b_full = np.zeros((nx, n + 2))
        x_full = np.zeros((nx, n + 2))
        a_full[:n_pack, :n_pack] = a
        b_full[:n_pack, 0] = b[:, 0]
        b_full[:n_pack, 2:] = b[:, 1:]
        x_full[:n_pack, 0] = x_ss[:, 0]
        x_full[:n_pack, 2:] = x_ss[:, 1:]
        law.fill(a_full, b_full, x_full, n_pack)
        self._modes = _decoupled_modes(self.transition, a_full, n_pack, pk)
        self._law_diagonal = np.arange(n_pack, nx)
        self._eye = np.eye(nx)
        self.law = law
        self.layout = layout
        self.a_matrix, self.b_matrix, self.static_gain = a_full, b_full, x_full
        self._spring = spring_force_matrix(n, pk.lamella_stiffness)
        self._work = np.zeros(layout.size)
        self._xbuf = np.empty(nx)
        self._xview = self._work[:nx]
        self._zview = self._work[:n_pack]
        law.bind(self._work, layout)
        self._cache = OrderedDict()
        self._last_key = None
        self._last_entry = None
        if kept is not None:
            self._cache, self._last_key, self._last_entry = kept
        self._area = pk.piston_area
        self._correction_weights = np.arange(1, n + 1, dtype=float)  # m of F_fm (N,)
        self._correction_div = n * pk.piston_area
        self._c2k = 2.0 * pk.effective_radius * pk.lamella_stiffness
        self._c2n = 2.0 * pk.effective_radius * n
        self._k_na = pk.lamella_stiffness / (n * pk.piston_area)  # p_eq = k z_N / (N A)
        self._set_friction(params)
        self._film = 1.0
        self._temp = params.friction.temperature_ref

    def _set_friction(self, params: ClutchParams) -> None:
        fr = params.friction
        self._fr = fr
        self._film_on = fr.film_depth > 0.0
        self._sign_speed = fr.sign_speed

    def discretisation(self, dt: float) -> _Entry:
        """Return the cached discretisation for ``dt`` [s] (``M = [Φ | Γ]``, see statespace)."""
        res = self.dt_resolution
        key = max(1, round(dt / res)) if res > 0.0 else dt
        last = self._last_entry
        if key == self._last_key and last is not None:  # (set together)
            return last
        entry = self._cache.get(key)
        if entry is not None:
            self._cache.move_to_end(key)  # least recently used is evicted first
        else:
            dtq = key * res if res > 0.0 else dt
            self.misses += 1
            phi = self._transition(dtq)
            gamma = (self._eye - phi) @ self.static_gain
            entry = _Entry(dtq, self.layout, np.hstack([phi, gamma]), self._spring)
            self.law.prepare(entry)
            self._cache[key] = entry
            while len(self._cache) > self.cache_size:
                self._cache.popitem(last=False)
        self._last_key, self._last_entry = key, entry
        return entry

    @property
    def transition_method(self) -> str:
        """How a new dt's ``e^{A dt}`` is computed here: ``"closed form"`` or ``"expm"``."""
        return "expm" if self._modes is None else "closed form"

    def _transition(self, dt: float) -> FloatArray:
        """``e^{A dt}`` of the pack and law system (closed form where decoupled, else expm)."""
        modes = self._modes
        if modes is None:
            return zoh_discretize(self.a_matrix, self.b_matrix, dt)[0]
        n_pack = 2 * modes.lamella_count
        phi = np.zeros_like(self.a_matrix)
        phi[:n_pack, :n_pack] = modes.transition(dt)
        law = self._law_diagonal  # the law's block is diagonal here
        phi[law, law] = np.exp(self.a_matrix[law, law] * dt)
        return phi

    # -- state ---------------------------------------------------------------------
    def reset(self, actuating_pressure: float = 0.0, lamella_temperature: float | None = None,
              slip_speed: float = 0.0) -> None:
        """Set the static equilibrium under ``actuating_pressure`` [Pa] (no spline force).

        Temperature [°C] (default ``friction.temperature_ref``; NaN = not measured: the
        thermal state starts at ``thermal.oil_temperature``) and slip speed [rad/s] set the
        law's rest state (ff_t's filter holds κ T of this operating point), the thermal state
        and the oil film (its equilibrium at this pressure and slip).
        """
        temp = self._fr.temperature_ref if lamella_temperature is None else lamella_temperature
        _check_finite(actuating_pressure, temp, slip_speed)
        if temp != temp:
            temp = self.params.thermal.oil_temperature
        lay = self.layout
        w = self._work
        force = actuating_pressure * self._area if actuating_pressure > 0.0 else 0.0
        w[:] = 0.0
        w[:lay.n_pack] = self.static_gain[:lay.n_pack, 0] * force
        self._temp = float(temp)
        self._film = film_equilibrium(self._fr, 1.0, actuating_pressure, slip_speed)
        mu = mu_scalar(self._fr, temp, actuating_pressure, slip_speed, self._film)
        load = mu * abs(sign_scalar(slip_speed, self._sign_speed))
        zn = w[lay.i_front]
        torque = self._c2k * load * zn if zn > 0.0 else 0.0
        w[lay.law_states] = self.law.equilibrium(torque)
        w[lay.i_force] = force
        w[lay.i_torque] = torque
        self.law.set_warm_state(None)

    @property
    def state(self) -> PackState:
        """A snapshot of the full state (pack, law, held inputs, film, temperature)."""
        return PackState(self.layout.lamella_count, self.law.name, self._work.copy(),
                         self.law.warm_state(), self._film, self._temp)

    def restore(self, state: PackState) -> None:
        """Return to a snapshot taken from a model with the same N and law."""
        if state.lamella_count != self.layout.lamella_count or state.law != self.law.name:
            raise InputError(f"snapshot is for N={state.lamella_count}/{state.law}, model is "
                             f"N={self.layout.lamella_count}/{self.law.name}")
        np.copyto(self._work, state.work)
        self.law.set_warm_state(state.warm)
        self._film, self._temp = state.film, state.temperature

    def copy(self) -> PackModel:
        """Return an independent model in the same state (shares the dt cache)."""
        other = PackModel.__new__(PackModel)
        other.dt_resolution, other.cache_size = self.dt_resolution, self.cache_size
        other.transition, other.misses = self.transition, 0
        other._configure(self.params)
        other._cache = self._cache
        other.restore(self.state)
        return other

    def set_params(self, params: ClutchParams) -> None:
        """Apply new parameters, keeping the state when N (and so its shape) is unchanged.

        Pack positions/velocities, film and thermal state are kept; the law's states are kept
        when the law is the same (ff_t's filter state y = κ·lowpass(T) is rescaled by
        κ_new/κ_old, as if the new κ had always applied), else the new law starts at rest (no
        force). A different N resets to equilibrium at the current actuating force. With the
        same pack and law parameters (the adaptation's friction scale, about once a second
        live) nothing is rebuilt: the same state, the same bits, in a few µs.
        """
        if params.pack == self.params.pack and params.spline == self.params.spline:
            self.params = self.law.params = params
            self._set_friction(params)
            return
        old_state, old_law = self._work.copy(), self.law
        old_layout = self.layout
        film, temp = self._film, self._temp
        self._configure(params)
        if params.pack.lamella_count != old_layout.lamella_count:
            self.reset(old_state[old_layout.i_force] / self._area, temp)
            return
        self._film, self._temp = film, temp
        lay = self.layout
        w = self._work
        w[:lay.n_pack] = old_state[:lay.n_pack]
        w[lay.i_force] = old_state[old_layout.i_force]
        torque = old_state[old_layout.i_torque]
        w[lay.i_torque] = torque
        if self.law.name == old_law.name:
            w[lay.law_states] = old_state[old_layout.law_states]
            w[lay.forces] = old_state[old_layout.forces]
            # the laws whose states scale with κ have a gain (the others no attribute)
            old_gain = getattr(old_law, "gain", 0.0)
            if self.law.states_scale_with_gain and old_gain > 0.0:
                w[lay.law_states] *= getattr(self.law, "gain", 0.0) / old_gain
            self.law.set_warm_state(old_law.warm_state())
        else:
            w[lay.law_states] = self.law.equilibrium(torque)
            self.law.set_warm_state(None)

    # -- stepping --------------------------------------------------------------------
    def step(self, dt: float, actuating_pressure: float, slip_speed: float,
             lamella_temperature: float) -> PackSample:
        """Advance by ``dt`` [s] with the sample's inputs held; return the outputs.

        ``lamella_temperature`` [°C] NaN means not measured: the thermal state is used.
        """
        if not (dt > 0.0 and math.isfinite(dt)):
            raise InputError(f"dt must be finite and > 0, got {dt!r}")
        _check_finite(actuating_pressure, lamella_temperature, slip_speed)
        entry = self.discretisation(dt)
        sign = sign_scalar(slip_speed, self._sign_speed)
        self._advance(entry, dt, actuating_pressure, slip_speed, lamella_temperature, sign)
        return self._sample(self._work.item(self.layout.i_force), actuating_pressure,
                            slip_speed, sign)

    def _advance(self, entry: _Entry, dt: float, pressure: float, omega: float,
                 temperature: float, sign: float) -> float:
        """One step (shared by step() and simulate()); returns the law's torque T [N m].

        μ is evaluated at the start of the step from the pack's own state: the pressure
        equivalent of its mean normal force ``k z_N / (N A)``, the film state and the
        temperature (measured, else the thermal state). Then the law's forces, the exact ZOH
        of the pack, and the film and thermal states with the same inputs held.
        """
        lay = self.layout
        w = self._work
        fr = self._fr
        temp = temperature if temperature == temperature else self._temp
        zn = w.item(lay.i_front)
        p_eq = zn * self._k_na if zn > 0.0 else 0.0
        mu = mu_scalar(fr, temp, p_eq, omega, self._film)
        load = mu * abs(sign)
        torque = self._c2k * load * zn if zn > 0.0 else 0.0
        w[lay.i_force] = pressure * self._area if pressure > 0.0 else 0.0
        w[lay.i_torque] = torque
        self.law.apply(entry, torque, load)
        np.dot(entry.M, w, out=self._xbuf)
        self._xview[:] = self._xbuf
        if self._film_on:
            self._film = film_step(fr, self._film, dt, p_eq, omega)
        if temperature == temperature:
            self._temp = temperature
        else:
            self._temp = thermal_step(self.params.thermal, temp, dt, torque * abs(omega))
        return torque

    def output(self, actuating_pressure: float, slip_speed: float,
               lamella_temperature: float) -> PackSample:
        """Return the outputs for the current state with these inputs, without advancing."""
        _check_finite(actuating_pressure, lamella_temperature, slip_speed)
        if lamella_temperature == lamella_temperature:
            self._temp = float(lamella_temperature)
        sign = sign_scalar(slip_speed, self._sign_speed)
        force = actuating_pressure * self._area if actuating_pressure > 0.0 else 0.0
        return self._sample(force, actuating_pressure, slip_speed, sign)

    def _sample(self, force: float, pressure: float, omega: float, sign: float) -> PackSample:
        normal = self._spring.dot(self._zview)
        zn = self._work.item(self.layout.i_front)
        p_eq = zn * self._k_na if zn > 0.0 else 0.0
        mu = mu_scalar(self._fr, self._temp, p_eq, omega, self._film)
        mu_ref = mu_scalar(self._fr, self._temp, pressure, omega)
        torque = self._c2k * mu * zn if zn > 0.0 else 0.0
        front = float(normal[-1]) / self._area
        rear = float(normal[0]) / self._area
        return PackSample(torque * sign, self._c2n * mu_ref * force * sign, mu, normal,
                          self.law.current_forces(), front, rear, front - rear, zn,
                          self._temp, self._film)

    # -- derived quantities -----------------------------------------------------------
    @property
    def positions(self) -> np.ndarray:
        """z_n rear → front [m]."""
        return self._work[0:self.layout.n_pack:2].copy()

    @property
    def velocities(self) -> np.ndarray:
        """ż_n rear → front [m/s]."""
        return self._work[1:self.layout.n_pack:2].copy()

    @property
    def spline_force(self) -> np.ndarray:
        """F_fn of the last step, rear → front [N] (see the law for held or end value)."""
        return self.law.current_forces()

    def spline_correction(self, forces: FloatArray | None = None) -> float:
        """Return the pressure equivalent of the current spline-friction loss [Pa].

        Quasi-statically a force F_fm on lamella m unloads the m springs behind it, so the
        springs carry ``N F_act − Σ_m m F_fm`` in total instead of ``N F_act``; the same total
        (and so the same Eq. 27 torque) needs ``Σ_m m F_fm / (N A)`` more pressure. Positive
        while compressing against spline friction, negative while it holds the pack
        compressed (rebound). The controller adds it to the steady-state inverse.
        ``forces``: the current spline forces if the caller has them (a
        :class:`PackSample`'s ``spline_force``), else they are asked of the law.
        """
        if forces is None:
            forces = self.law.current_forces()
        return float(self._correction_weights.dot(forces)) / self._correction_div


def _decoupled_modes(transition: str, a_full: FloatArray, n_pack: int,
                     pack: PackParams) -> PackModes | None:
    """Return the closed-form modes if ``transition`` allows and the law's states decouple.

    Decoupled: no law state enters the pack's rows, no pack state the law's rows, and the
    law's block is diagonal (each state a first-order lag of held inputs), so
    ``e^{A dt} = diag(e^{A_pack dt}, e^{a_ii dt})``. ``ff_t_printed`` (its filter state acts
    on the pack inside the step) and ``ff_v``/``ff_v_printed`` (driven by the lamella speeds)
    are not, and keep ``expm``.
    """
    if transition != "auto":
        return None
    law_block = a_full[n_pack:, n_pack:]
    if (a_full[:n_pack, n_pack:].any() or a_full[n_pack:, :n_pack].any()
            or np.count_nonzero(law_block - np.diag(np.diagonal(law_block)))):
        return None
    return PackModes(pack.lamella_count, pack.lamella_mass, pack.lamella_stiffness,
                     pack.lamella_damping)


def _check_finite(pressure: float, temperature: float, slip_speed: float) -> None:
    """Pressure and slip must be finite; the temperature finite or NaN (not measured)."""
    if not (math.isfinite(pressure) and not math.isinf(temperature)
            and math.isfinite(slip_speed)):
        raise NonFiniteSample(f"non-finite input: actuating_pressure={pressure!r}, "
                              f"lamella_temperature={temperature!r}, slip_speed={slip_speed!r}")
