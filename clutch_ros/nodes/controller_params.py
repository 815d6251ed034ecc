"""The controller node's parameters (``controller.*``): unit, range, description, defaults.

Every one applies live (the node validates a change as a whole and applies it from the next
tick, :mod:`clutch_ros.nodes.controller`). Every default of a control-law setting comes from
:class:`clutch_ros.model.controller_settings.ControllerSettings` (written once, there;
``controller.rate`` is ``1 / period``); :func:`controller_settings` turns the declared values
back into settings (the model validates them and raises a ClutchError with its reason). The
input timeouts and ``controller.use_adapted_model`` belong to the node alone and are written
here.
"""

from __future__ import annotations

from clutch_ros.model.controller_settings import ControllerSettings
from clutch_ros.nodes.parameters import HARDWARE_ID_PARAM, ParamSpec

__all__ = ["PARAMS", "RIG_TIMEOUT", "TIMEOUTS", "TRIGGERS", "WATCHDOG_FRACTION",
           "controller_settings"]

#: values of ``controller.trigger``: what runs a control step
TRIGGERS = ("timer", "estimate")
#: ``controller.trigger`` "estimate": the fail-safe check runs every this fraction of the
#: shortest input timeout, so 0 Pa follows at most 1.25 timeouts after an input stopped
WATCHDOG_FRACTION = 0.25

#: [s] default ``controller.rig_timeout``: rig_state older than this is stale (also the
#: can_bridge's publishing-lag warning, :data:`clutch_ros.nodes.can_diagnostics.LAG_WARN`)
RIG_TIMEOUT = 0.25
_C = ControllerSettings()  # the defaults of the control-law parameters
PARAMS = [
    ParamSpec("controller.rate", 1.0 / _C.period, "command publishing rate", "Hz", 1.0,
              2000.0),
    ParamSpec("controller.min_pressure", _C.min_pressure, "lowest commanded pressure", "Pa",
              0.0, 1e8),
    ParamSpec("controller.max_pressure", _C.max_pressure, "highest commanded pressure", "Pa",
              0.0, 1e8),
    ParamSpec("controller.rise_rate_limit", _C.rise_rate_limit, "maximum pressure rise; below "
              "the pump's kick threshold (about 100 bar/s, thesis 5.1.1)", "Pa/s", 1.0, 1e10),
    ParamSpec("controller.fall_rate_limit", _C.fall_rate_limit, "maximum pressure fall "
              "(fail-safe zeroing bypasses it)", "Pa/s", 1.0, 1e10),
    ParamSpec("controller.torque_ramp_rate", _C.torque_ramp_rate, "maximum slew of the torque "
              "target (request ramping)", "N m/s", 1.0, 1e7),
    ParamSpec("controller.lead_time", _C.lead_time, "the target is advanced by lead_time x the "
              "request slope: pack lag c/k (0.1 s), pump lag (~0.05 s) and transport delay",
              "s", 0.0, 2.0),
    ParamSpec("controller.fall_lead_time", _C.fall_lead_time, "lead_time on a falling "
              "request: pump lag, transport delay and the pack's hysteresis at the reversal "
              "add up there", "s", 0.0, 2.0),
    ParamSpec("controller.lead_max_rate", _C.lead_max_rate, "bound of the request slope used "
              "by the lead (steps are not differentiated into spikes); a faster request change "
              "is a step (the trim holds, trim_delay)", "N m/s", 0.0, 1e6),
    ParamSpec("controller.overshoot_margin", _C.overshoot_margin, "overshoot guard: pressure "
              "never above the steady-state inverse of (1 + margin) x request", "1", 0.0, 1.0),
    ParamSpec("controller.spline_correction_gain", _C.correction_gain, "weight of the dynamic "
              "spline-friction correction (0 = steady-state inverse only)", "1", 0.0, 2.0),
    ParamSpec("controller.use_adapted_model", True, "invert the model with the estimate's "
              "adapted friction_scale (and spline_gain_scale)"),
    ParamSpec("controller.trim_rate", _C.trim_rate, "integral gain of the torque trim on the "
              "measured torque, 1/its time constant; 0 = off (off anyway without a "
              "measurement)", "1/s", 0.0, 100.0),
    ParamSpec("controller.trim_limit", _C.trim_limit, "bound of the trim, a fraction of the "
              "request", "1", 0.0, 1.0),
    ParamSpec("controller.trim_delay", _C.trim_delay, "the trim holds this long after a step "
              "of the request (the pack's step transient)", "s", 0.0, 10.0),
    ParamSpec("controller.trim_settle_time", _C.trim_settle_time, "up to this long after a "
              "step the trim also holds while the model-vs-measured error is beyond its bounds "
              "(trim_limit: the step's transient)", "s", 0.0, 30.0),
    ParamSpec("controller.trim_hold", _C.trim_hold, "a torque measurement missing for up to "
              "this long holds the trim (a late frame); longer releases it", "s", 0.0, 10.0),
    ParamSpec("controller.uncertainty_margin", _C.uncertainty_margin, "while the trim can act, "
              "invert the model with the friction scale at s + margin x friction_scale_std "
              "(its upper confidence bound, in standard deviations): an unlearned mu is "
              "approached from below and the trim closes the gap; 0 = the estimate s; taken "
              "at the next change of the request", "1", 0.0, 5.0),
    ParamSpec("controller.uncertainty_range", _C.uncertainty_range, "the start: no friction "
              "scale within s +- range x friction_scale_std (the prior's before anything is "
              "learned) may overshoot by more than overshoot_margin: the scale inverted is at "
              "least (s + range x std) / (1 + overshoot_margin) and the trim reaches the whole "
              "range; 0 = off", "1", 0.0, 5.0),
    ParamSpec("controller.start_trim_delay", _C.start_trim_delay, "trim_delay of a step taken "
              "with the start's caution (uncertainty_range)", "s", 0.0, 10.0),
    ParamSpec("controller.request_timeout", 0.5, "a torque request older than this is stale "
              "-> 0 Pa", "s", 0.001, 3600.0),
    ParamSpec("controller.rig_timeout", RIG_TIMEOUT, "rig_state older than this is stale -> 0 Pa",
              "s", 0.001, 3600.0),
    ParamSpec("controller.estimate_timeout", 0.25, "clutch_estimate older than this is stale "
              "-> 0 Pa", "s", 0.001, 3600.0),
    ParamSpec("controller.trigger", "timer", "what runs a control step: 'timer' every "
              "1/controller.rate; 'estimate' one step per clutch_estimate, the command stamped "
              "with the estimate's stamp (it names the estimate it answers: lock-step), "
              "controller.rate then the estimates' rate (an estimate stamped less than half a "
              "period after the last step's is skipped) and the fail-safe checked every quarter "
              "of the shortest input timeout; read-only: fixed at start", choices=TRIGGERS,
              read_only=True),
    HARDWARE_ID_PARAM,
]


#: input -> its timeout parameter
TIMEOUTS = {"torque request": "controller.request_timeout", "rig data": "controller.rig_timeout",
            "estimate": "controller.estimate_timeout"}


def controller_settings(cfg: dict) -> ControllerSettings:
    """Return the ControllerSettings of the ``controller.*`` values ``cfg`` (may raise)."""
    return ControllerSettings(
        period=1.0 / cfg["controller.rate"], min_pressure=cfg["controller.min_pressure"],
        max_pressure=cfg["controller.max_pressure"],
        rise_rate_limit=cfg["controller.rise_rate_limit"],
        fall_rate_limit=cfg["controller.fall_rate_limit"],
        torque_ramp_rate=cfg["controller.torque_ramp_rate"],
        lead_time=cfg["controller.lead_time"], lead_max_rate=cfg["controller.lead_max_rate"],
        fall_lead_time=cfg["controller.fall_lead_time"],
        overshoot_margin=cfg["controller.overshoot_margin"],
        correction_gain=cfg["controller.spline_correction_gain"],
        trim_rate=cfg["controller.trim_rate"], trim_limit=cfg["controller.trim_limit"],
        trim_delay=cfg["controller.trim_delay"], trim_hold=cfg["controller.trim_hold"],
        trim_settle_time=cfg["controller.trim_settle_time"],
        uncertainty_margin=cfg["controller.uncertainty_margin"],
        uncertainty_range=cfg["controller.uncertainty_range"],
        start_trim_delay=cfg["controller.start_trim_delay"])
