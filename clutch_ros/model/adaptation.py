"""Online adaptation of the friction scale (and, where identifiable, the spline gain).

Why a friction scale: the rig's friction coefficient differs from the preset's and drifts with
temperature and wear; a torque flange measures what the pack really transmits. The adapted
quantity is a multiplier ``s`` of μ (``friction.mu_ref`` and ``friction.mu_min`` both times
``s``, so ``μ = max(s μ_min, s μ_ref f_T f_p f_ω) = s μ`` exactly). Choice, and why it is the
physically right one rather than scaling the output torque: μ enters the pack model twice,
in the transmitted torque (Eq. 27, ``2 μ R_e Σ S_n``) *and* in the torque the spline laws see
(ff_t's force follows the transmitted torque, coulomb's ``a = μ μ_s R_e / r_s``); a higher μ
means a higher tangential load on the splines and so more spline friction. Scaling only the
output would adapt the torque level but leave the spline forces, P_diff and the controller's
spline correction at the old μ. So the adapted ``s`` is applied to the model's parameters
(:func:`scaled_params`) and the same parameters are what ``--save-params`` writes and what
the controller inverts.

Estimator: :class:`~clutch_ros.model.parameter_filter.ParameterFilter`, recursive least
squares with exponential forgetting (by the time that adaptation ran, ``forgetting_time``),
bounds (scale in ``[scale_min, scale_max]``) and the parameters' covariance, whose
``sqrt(P_ii)`` is the reported standard deviation; its module docstring gives the update.

Regression: the estimate of the model at the applied parameters ``θ_a`` is ``T(θ_a)``;
linearised, ``y ≈ T(θ_a) + J (θ − θ_a)`` with ``J = [T/s_a, ∂T/∂g]`` (torque is linear in
``s`` at a given pack state; ``∂T/∂g`` is the finite-difference sensitivity to the relative
spline gain ``g = κ/κ_0`` from a shadow estimator at ``g (1 + δ)``). So the regression is
``y − T(θ_a) + J θ_a = J θ``. The friction-scale part is exact (linear); the spline-gain part
is a linearisation (an extended-Kalman-style update) and is offered only for laws with a gain
(``ff_t``, ``ff_v``) and updated only while its sensitivity exceeds
``min_gain_sensitivity`` [N m] (transients: at steady state both thesis laws give no spline
force, so the gain is not identifiable there).

Guards (per sample; any failing one pauses or freezes adaptation, the estimate goes on):
a measurement must be present (``has_measured_torque``; NaN = absent; missing for longer
than ``dropout_grace`` it is a dropout, shorter only a late frame) and plausible (finite,
same sign as the model, ``|y| / |T_1|`` within ``[scale_min, scale_max]`` widened by
``plausibility_margin``, where ``T_1`` is the model torque at ``s = 1``); after a dropout or
an implausible value it must be plausible for ``recover_time`` before adapting resumes;
``|T| >= min_torque`` and ``|ω_f| >= min_slip`` (below, static friction and noise dominate);
for the friction scale, quasi-steady operation: ``|dT/dt| <= max_torque_rate`` for at least
``settle_time`` (step transients are the pack dynamics' and the spline law's error, not
friction's; the spline gain, whose information is in those transients, adapts there);
not a re-initialised sample. A lost or implausible measurement *freezes*
the adaptation (state ``frozen``, what was learned is kept and used, a diagnostic says why);
the other guards only *pause* it (state ``paused``).

Units: torque [N m], slip speed [rad/s], time [s]; scales are dimensionless.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

from clutch_ros.model.errors import ModelError
from clutch_ros.model.estimator import ClutchEstimator, Estimate
from clutch_ros.model.inverse import capacity_scalar
from clutch_ros.model.laws import LawNames
from clutch_ros.model.parameter_filter import ParameterFilter

if TYPE_CHECKING:
    from clutch_ros.model.params import ClutchParams

__all__ = ["AdaptationSettings", "AdaptationStatus", "AdaptiveEstimate", "AdaptiveEstimator",
           "GAIN_LAWS", "fork_estimator", "scaled_params"]

#: Spline laws whose ``spline.gain`` the adaptation may estimate (a live view of the
#: registry's :attr:`~clutch_ros.model.laws.SplineLawInfo.adapts_gain`).
GAIN_LAWS = LawNames("adapts_gain")


def fork_estimator(estimator: ClutchEstimator, params: ClutchParams | None = None,
                   **kwargs: Any) -> ClutchEstimator:
    """Return an independent :class:`ClutchEstimator` in the same state as ``estimator``.

    Pack state (:meth:`PackModel.restore`), slip filter, drivetrain compliance and clock are
    copied; ``params`` (default: the same) are then applied with
    :meth:`ClutchEstimator.set_params`, so a changed spline gain rescales the law's state as
    if it had always applied. (``deepcopy`` is not an option: the pack's state vector has
    numpy views that a deep copy detaches.)
    ``kwargs`` are the estimator's constructor options.
    """
    other = ClutchEstimator(estimator.params, **kwargs)
    other.pack.restore(estimator.pack.state)
    other.slip_filter = copy.copy(estimator.slip_filter)
    other.last_stamp = estimator.last_stamp
    if estimator.drive is not None and other.drive is not None:  # the compliance's state
        other.drive.state[:] = estimator.drive.state
    if params is not None:
        other.set_params(params)
    return other


def scaled_params(params: ClutchParams, friction_scale: float,
                  gain_scale: float = 1.0) -> ClutchParams:
    """Return ``params`` with μ scaled by ``friction_scale`` and the spline gain by ``gain_scale``.

    μ_ref and μ_min are both multiplied, so μ itself is multiplied exactly (module docstring).
    ``spline.gain`` is multiplied only for laws with a gain (:data:`GAIN_LAWS`).
    """
    if not (friction_scale > 0.0 and gain_scale > 0.0
            and math.isfinite(friction_scale) and math.isfinite(gain_scale)):
        raise ModelError(f"scales must be finite and > 0, got {friction_scale!r}, "
                         f"{gain_scale!r}")
    fr = params.friction
    changes = {"friction.mu_ref": fr.mu_ref * friction_scale,
               "friction.mu_min": fr.mu_min * friction_scale}
    if params.spline.law in GAIN_LAWS and gain_scale != 1.0:
        changes["spline.gain"] = params.spline.gain * gain_scale
    return params.updated(changes)


@dataclass(frozen=True)
class AdaptationSettings:
    """Tunables of the adaptation (the estimator node's ``adapt.*`` parameters, SI).

    Attributes:
        enabled: adapt when a plausible torque measurement is present [bool]
        forgetting_time: memory of the estimator, in adaptation time [s]
        scale_min, scale_max: bounds of the friction scale [1]
        initial_std: prior standard deviation of the friction scale [1]
        measurement_std: absolute standard deviation of the torque error [N m]
        relative_std: relative standard deviation of the torque error [1]
        min_torque: adapt only above this |modelled torque| [N m]
        min_slip: adapt only above this |filtered slip speed| [rad/s]
        max_torque_rate: adapt the friction scale only below this |d modelled torque / dt|
            [N m/s] ...
        settle_time: ... and this long after it last exceeded it [s] (the spline laws'
            transients last about spline.time_constant, ~1 s)
        plausibility_margin: widening of the scale bounds for the plausibility check [1]
        recover_time: plausible measurements needed after a dropout before adapting [s]
        dropout_grace: a measurement missing for up to this long only pauses adaptation (a
            late CAN frame: the bridge marks a stale torque frame as no measurement); longer,
            it is a dropout: frozen, with a diagnostic [s]
        apply_tolerance: re-apply the parameters when a scale moved by this fraction [1]
        apply_interval: ... and at most this often [s] (each application re-discretises
            the pack, a matrix exponential of ~1-10 ms)
        spline_gain: also adapt the spline gain (ff_t, ff_v only) [bool]
        gain_min, gain_max: bounds of the relative spline gain κ/κ_0 [1]
        gain_initial_std: prior standard deviation of the relative spline gain [1]
        gain_step: relative perturbation of the sensitivity estimator [1]
        min_gain_sensitivity: adapt the gain only while |∂T/∂g| exceeds this [N m]

    """

    enabled: bool = True
    forgetting_time: float = 30.0
    scale_min: float = 0.5
    scale_max: float = 2.0
    initial_std: float = 0.2
    measurement_std: float = 10.0
    relative_std: float = 0.02
    min_torque: float = 50.0
    min_slip: float = 0.5
    max_torque_rate: float = 1500.0
    settle_time: float = 1.0
    plausibility_margin: float = 0.25
    recover_time: float = 0.5
    dropout_grace: float = 0.25
    apply_tolerance: float = 2e-3
    apply_interval: float = 1.0
    spline_gain: bool = False
    gain_min: float = 0.2
    gain_max: float = 5.0
    gain_initial_std: float = 0.5
    gain_step: float = 0.05
    min_gain_sensitivity: float = 5.0

    def __post_init__(self) -> None:
        checks = {
            "forgetting_time": self.forgetting_time > 0.0,
            "scale_min": 0.0 < self.scale_min <= 1.0,
            "scale_max": 1.0 <= self.scale_max,
            "initial_std": self.initial_std > 0.0,
            "measurement_std": self.measurement_std > 0.0,
            "relative_std": self.relative_std >= 0.0,
            "min_torque": self.min_torque >= 0.0, "min_slip": self.min_slip >= 0.0,
            "max_torque_rate": self.max_torque_rate > 0.0,
            "settle_time": self.settle_time >= 0.0,
            "plausibility_margin": self.plausibility_margin >= 0.0,
            "recover_time": self.recover_time >= 0.0,
            "dropout_grace": self.dropout_grace >= 0.0,
            "apply_tolerance": self.apply_tolerance >= 0.0,
            "apply_interval": self.apply_interval >= 0.0,
            "gain_min": 0.0 < self.gain_min <= 1.0, "gain_max": 1.0 <= self.gain_max,
            "gain_initial_std": self.gain_initial_std > 0.0,
            "gain_step": 0.0 < self.gain_step <= 0.5,
            "min_gain_sensitivity": self.min_gain_sensitivity >= 0.0,
        }
        for name, ok in checks.items():
            value = getattr(self, name)
            if not ok or (isinstance(value, float) and math.isnan(value)):
                raise ModelError(f"adaptation setting {name} out of range: {value!r}")


@dataclass(frozen=True)
class AdaptationStatus:
    """The adaptation at one sample (mirrors the ClutchEstimate adaptation fields).

    Attributes:
        friction_scale: the adapted μ multiplier the model of this estimate ran with [1]
            (the estimate is applied in steps, ``apply_tolerance``/``apply_interval``; the
            latest value is :attr:`AdaptiveEstimator.friction_scale`)
        friction_scale_std: its standard deviation [1]
        spline_gain_scale: adapted κ/κ_0 the model ran with [1] (1 when the law has none)
        spline_gain_scale_std: its standard deviation [1]
        adapting: the parameters were updated at this sample
        state: ``adapting`` | ``paused`` | ``frozen`` | ``waiting`` | ``off``
        reason: why not adapting (empty while adapting)

    """

    friction_scale: float
    friction_scale_std: float
    spline_gain_scale: float
    spline_gain_scale_std: float
    adapting: bool
    state: str
    reason: str


@dataclass
class AdaptiveEstimate:
    """One sample: the model's :class:`Estimate` and the :class:`AdaptationStatus`."""

    estimate: Estimate
    adaptation: AdaptationStatus


@dataclass
class _Guard:
    seen_measurement: bool = False
    implausible: bool = False
    plausible_since: float | None = None
    last_torque: float | None = None
    last_stamp: float | None = None
    last_fast: float = -math.inf
    missing_since: float | None = None
    counts: dict[str, int] = field(default_factory=lambda: {"adapting": 0, "paused": 0,
                                                             "frozen": 0,
                                                  "waiting": 0, "off": 0,
                                                  "dropouts": 0, "implausible": 0})


class AdaptiveEstimator:
    """:class:`ClutchEstimator` with online adaptation of μ (and the spline gain).

    Composes, never edits, the estimator: the adapted parameters are applied with
    :meth:`ClutchEstimator.set_params` (pack state kept) whenever a scale moved by more than
    ``apply_tolerance``. ``update`` takes the estimator's arguments (a NaN ``measured_torque``
    is "no measurement") and returns an :class:`AdaptiveEstimate`.

    Args:
        params: base :class:`~clutch_ros.model.params.ClutchParams` (scale 1)
        settings: :class:`AdaptationSettings`
        friction_scale, spline_gain_scale: starting values (e.g. from a saved run) [1]
        **estimator_kwargs: passed to :class:`ClutchEstimator`

    """

    def __init__(self, params: ClutchParams, settings: AdaptationSettings | None = None, *,
                 friction_scale: float = 1.0, spline_gain_scale: float = 1.0,
                 **estimator_kwargs: Any) -> None:
        self.settings = s = settings or AdaptationSettings()
        self.base_params = params
        self._kwargs = estimator_kwargs
        self.gain_identifiable = s.spline_gain and params.spline.law in GAIN_LAWS
        gain0 = spline_gain_scale if params.spline.law in GAIN_LAWS else 1.0
        self.filter = ParameterFilter(
            [min(max(friction_scale, s.scale_min), s.scale_max),
             min(max(gain0, s.gain_min), s.gain_max)],
            [s.initial_std, s.gain_initial_std], [s.scale_min, s.gain_min],
            [s.scale_max, s.gain_max])
        self.applied = list(self.filter.theta)
        self._applied_at: float | None = None
        self.estimator = ClutchEstimator(self.adapted_params(), **estimator_kwargs)
        self._shadow: ClutchEstimator | None = None
        self._guard = _Guard()
        self.status = self._status(False, "off" if not s.enabled else "waiting",
                                   "adaptation off" if not s.enabled
                                   else "no torque measurement yet")

    # -- parameters -------------------------------------------------------------------
    @property
    def friction_scale(self) -> float:
        """Current friction scale estimate [1]."""
        return float(self.filter.theta[0])

    @property
    def spline_gain_scale(self) -> float:
        """Current relative spline gain κ/κ_0 estimate [1]."""
        return float(self.filter.theta[1])

    @property
    def counts(self) -> dict[str, int]:
        """Samples per state and the number of dropouts / implausible measurements."""
        return dict(self._guard.counts)

    def adapted_params(self) -> ClutchParams:
        """Return the base parameters with the current estimates applied (what is saved)."""
        return scaled_params(self.base_params, self.friction_scale, self.spline_gain_scale)

    def set_base_params(self, params: ClutchParams) -> None:
        """Replace the base parameters (e.g. a live parameter change); the scales stay."""
        self.base_params = params
        self.gain_identifiable = self.settings.spline_gain and params.spline.law in GAIN_LAWS
        self._apply(force=True)

    def reset(self) -> None:
        """Forget the time history (a new recording starts); keep what was learned."""
        self.estimator.reset()
        self._shadow = None
        g = self._guard
        g.last_stamp = g.last_torque = g.plausible_since = g.missing_since = None
        g.last_fast = -math.inf

    def set_enabled(self, enabled: bool) -> None:
        """Switch adaptation on or off at runtime (what was learned is kept either way)."""
        self.set_settings(replace(self.settings, enabled=bool(enabled)))

    def set_settings(self, settings: AdaptationSettings) -> None:
        """Apply new settings at runtime: new bounds clip the estimates, the rest is kept."""
        self.settings = settings
        f = self.filter
        f.lower[0], f.upper[0] = settings.scale_min, settings.scale_max
        f.lower[1], f.upper[1] = settings.gain_min, settings.gain_max
        f.theta[0] = min(max(f.theta[0], f.lower[0]), f.upper[0])
        f.theta[1] = min(max(f.theta[1], f.lower[1]), f.upper[1])
        self.gain_identifiable = settings.spline_gain and self.base_params.spline.law in GAIN_LAWS
        self._apply(force=True)

    def _apply(self, now: float | None = None, force: bool = False) -> None:
        theta = self.filter.theta
        s = self.settings
        moved = any(abs(v - a) > s.apply_tolerance * a for v, a in zip(theta, self.applied))
        due = (self._applied_at is None or now is None
               or now - self._applied_at >= s.apply_interval)
        if force or (moved and due):
            self.applied, self._applied_at = list(theta), now
            self.estimator.set_params(self.adapted_params())
            self._shadow = None

    def _start_shadow(self) -> None:
        """Fork the shadow estimator (same state, gain g (1 + δ)) before a sample."""
        if self._shadow is None:
            self._shadow = fork_estimator(self.estimator, scaled_params(
                self.base_params, self.applied[0],
                self.applied[1] * (1.0 + self.settings.gain_step)), **self._kwargs)

    def _sensitivity(self, est: Estimate, args: tuple[float, float, float, float, float],
                     ) -> float:
        """∂T/∂g [N m per unit relative gain] by the shadow estimator at g (1 + δ)."""
        assert self._shadow is not None  # update() forks it first (_start_shadow)
        shadow = self._shadow.update(*args)
        step = self.applied[1] * self.settings.gain_step
        return (shadow.modelled_torque - est.modelled_torque) / step

    def _out_of_range(self, y: float, temperature: float) -> str:
        """Return why ``y`` [N m] is beyond any torque the clutch can transmit, or ''."""
        s = self.settings
        cap = capacity_scalar(self.base_params, self.base_params.pack.max_pressure,
                              temperature, 0.0)  # static μ: the largest torque at this T
        high = s.scale_max * (1.0 + s.plausibility_margin) * cap
        if abs(y) > high:
            return f"|{y:.1f}| N m above the {high:.1f} N m the clutch can transmit"
        return ""

    def _implausible(self, y: float, unit: float) -> str:
        """Return why ``y`` [N m] is not explained by an allowed scale of ``unit``, or ''.

        Only asked in quasi-steady operation (the pause guards passed), where the model
        torque at scale 1, ``unit`` [N m], is large and slowly changing.
        """
        s = self.settings
        widen = 1.0 + s.plausibility_margin
        if y * unit <= 0.0:
            return f"{y:.1f} N m has not the sign of the model's {unit:.1f} N m"
        ratio = y / unit
        if not s.scale_min / widen <= ratio <= s.scale_max * widen:
            return (f"measured/model ratio {ratio:.3f} outside [{s.scale_min / widen:.3f}, "
                    f"{s.scale_max * widen:.3f}]")
        return ""

    # -- per sample -------------------------------------------------------------------
    def update(self, stamp_s: float, actuating_pressure: float, lamella_temperature: float,
               slip_speed: float, measured_torque: float = math.nan) -> AdaptiveEstimate:
        """Estimate one sample, then adapt on it when the guards allow (module docstring).

        Raises the estimator's SampleRejected for a bad sample (nothing changes then).
        """
        args = (stamp_s, actuating_pressure, lamella_temperature, slip_speed, measured_torque)
        self.estimator.check(*args)
        if self.gain_identifiable:
            self._start_shadow()
        est = self.estimator.update(*args)
        sens = self._sensitivity(est, args) if self.gain_identifiable else 0.0
        status = self._adapt(est, sens)
        self._apply(est.stamp)
        return AdaptiveEstimate(est, status)

    def _status(self, adapting: bool, state: str, reason: str) -> AdaptationStatus:
        std = self.filter.std
        return AdaptationStatus(self.applied[0], float(std[0]), self.applied[1],
                                float(std[1]) if self.gain_identifiable else 0.0,
                                adapting, state, reason)

    def _finish(self, adapting: bool, state: str, reason: str) -> AdaptationStatus:
        self._guard.counts[state] += 1
        self.status = self._status(adapting, state, reason)
        return self.status

    def _adapt(self, est: Estimate, sensitivity: float) -> AdaptationStatus:
        s, g = self.settings, self._guard
        t, torque, y = est.stamp, est.modelled_torque, est.measured_torque
        rate = (math.inf if g.last_stamp is None or g.last_torque is None or est.reinitialised
                else abs(torque - g.last_torque) / (t - g.last_stamp))  # (set together)
        dt = 0.0 if g.last_stamp is None else t - g.last_stamp
        g.last_stamp, g.last_torque = t, torque
        if not s.enabled:
            return self._finish(False, "off", "adaptation off")
        if math.isnan(y):
            g.implausible = False
            if not g.seen_measurement:
                return self._finish(False, "waiting", "no torque measurement yet")
            if g.missing_since is None:
                g.missing_since = t
            if t - g.missing_since <= s.dropout_grace:
                return self._finish(False, "paused", "torque measurement missing")
            g.plausible_since = None
            if not self.status.reason.startswith("torque measurement dropped"):
                g.counts["dropouts"] += 1
            return self._finish(False, "frozen", "torque measurement dropped out; "
                                "adapted values kept")
        g.seen_measurement = True
        g.missing_since = None
        if rate > s.max_torque_rate:
            g.last_fast = t
        settled = t - g.last_fast >= s.settle_time
        why = self._out_of_range(y, est.lamella_temperature)
        unit = torque / self.applied[0]  # model torque at s = 1 [N m]
        reason = ""
        if est.reinitialised or dt <= 0.0:
            reason = "estimator (re)initialised"
        elif abs(torque) < s.min_torque:
            reason = f"torque below {s.min_torque:g} N m"
        elif abs(est.slip_speed_filtered) < s.min_slip:
            reason = f"slip below {s.min_slip:g} rad/s"
        if not why and not reason and settled:
            why = self._implausible(y, unit)
        if why:
            g.counts["implausible"] += not g.implausible
            g.implausible, g.plausible_since = True, None
            return self._finish(False, "frozen", f"implausible torque measurement: {why}")
        if reason:
            return self._finish(False, "paused", reason)
        g.implausible = False
        if g.plausible_since is None:
            g.plausible_since = t
        if t - g.plausible_since < s.recover_time:
            return self._finish(False, "paused", "measurement plausible again; waiting "
                                f"{s.recover_time:g} s before adapting")
        gain_on = self.gain_identifiable and abs(sensitivity) >= s.min_gain_sensitivity
        if not (settled or gain_on):
            return self._finish(False, "paused", f"transient: torque changed faster than "
                                f"{s.max_torque_rate:g} N m/s within {s.settle_time:g} s")
        phi = (unit, sensitivity)
        target = y - torque + unit * self.applied[0] + sensitivity * self.applied[1]
        noise = s.measurement_std ** 2 + (s.relative_std * y) ** 2
        self.filter.update(phi, target, noise, math.exp(-dt / s.forgetting_time),
                           (settled, gain_on))
        return self._finish(True, "adapting", "")
