"""The ``estimator`` node: RigState in, ClutchEstimate out, one per accepted sample.

``estimator.publish_every`` N > 1 publishes only every Nth accepted estimate (the first, the
N+1th, ...) for consumers that need less; the model still runs on every sample. Bags and
the regression want every sample: leave it at 1 for them.

Runs the model core's :class:`clutch_ros.model.ClutchEstimator` (lamella pack + spline-friction
law) on every ``rig_state`` sample, using the message stamps for time (never wall time), so a
bag replayed at any speed gives the same estimates. Samples that are NaN/inf, out of order,
duplicated or older than ``estimator.max_sample_age`` are skipped, counted and reported on
``/diagnostics``; a NaN torque is never published. Model parameters are the README.md keys
(``clutch.*``, ``friction.*``, ``spline.*``, ``slip.*``); runtime changes are validated by the
model and rejected with its reason (their ranges are the model's, stated in the descriptors'
``additional_constraints``), and applied without losing the pack state.

Online adaptation (:mod:`clutch_ros.model.adaptation`, parameters ``adapt.*``): while a
plausible torque measurement is present (``has_measured_torque``) and the clutch slips under
load, a friction scale (a multiplier of μ) is estimated by recursive least squares with
forgetting and applied to the model; ``ClutchEstimate`` carries it (``friction_scale``,
``friction_scale_std``, ``spline_gain_scale``, ``adapting``, ``adaptation_frozen``). When the
measurement drops out or turns implausible the adaptation freezes, keeps what it learned, and
``/diagnostics`` says so (WARN, with the reason). Setting ``adapt.save_params_file`` to a path
writes the adapted parameters there as a complete parameter file (``ros2 param set
/estimator adapt.save_params_file /path/adapted.yaml``); the nodes and every ``clutch``
subcommand accept it.
"""

from __future__ import annotations

import math

from clutch_msgs.msg import ClutchEstimate, RigState
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node

from clutch_ros import interfaces
from clutch_ros.config.params_file import load_flat
from clutch_ros.config.presets import default_preset
from clutch_ros.errors import ClutchError
from clutch_ros.model import SampleRejected
from clutch_ros.model.adaptation import AdaptiveEstimator
from clutch_ros.model.uncertainty import TorqueStd
from clutch_ros.nodes.adapt_params import ADAPT_PARAMS, adapt_settings
from clutch_ros.nodes.convert import CdrCodec, EstimateEncoder
from clutch_ros.nodes.diagnostics import Diagnostics, LogThrottle
from clutch_ros.nodes.loss_tracker import LossTracker
from clutch_ros.nodes.model_params import (
    apply_model_changes,
    declare_model_params,
    model_param_specs,
)
from clutch_ros.nodes.parameters import HARDWARE_ID_PARAM, ParamSpec, declare_params
from clutch_ros.nodes.peers import Input, PeerWatch
from clutch_ros.nodes.qos import publisher_qos, subscriber_qos
from clutch_ros.nodes.runner import run_node
from clutch_ros.nodes.uncertainty_params import UNCERTAINTY_PARAMS, error_model
from clutch_ros.offline.adapt import save_adapted_params

NAME = "estimator"
_RIG_STATE, _CLUTCH_ESTIMATE = interfaces.RIG_STATE.name, interfaces.CLUTCH_ESTIMATE.name
DRAIN_MAX = 50  # queued rig_state samples taken per callback, beyond the one it was called for
#: the RigState fields the estimator reads (their positions in CdrCodec(RigState).names)
_INPUTS = ("header.stamp.sec", "header.stamp.nanosec", "header.frame_id", "actuating_pressure",
           "lamella_temperature", "slip_speed", "measured_torque", "has_measured_torque")
PARAMS = [
    ParamSpec("estimator.max_sample_age", 0.5, "skip samples whose stamp is older than this "
              "relative to the node clock; 0 disables the check", "s", 0.0, 3600.0),
    ParamSpec("estimator.input_timeout", 0.5, "no input for longer than this is reported as "
              "stale on /diagnostics", "s", 0.001, 3600.0),
    ParamSpec("estimator.queue_depth", 200, "rig_state subscription queue (sensor-data QoS, "
              "best effort); samples lost anyway are counted; read-only: a DDS reader's "
              "history depth is fixed when the subscription is created", "messages", 1, 100000,
              read_only=True),
    ParamSpec("estimator.publish_every", 1, "publish every Nth accepted estimate (the first, "
              "the N+1th, ...); the model still runs on every sample; bags and regression "
              "use 1", "samples", 1, 100000),
    ParamSpec("estimator.max_gap", 1.0, "a gap between samples longer than this re-initialises "
              "the pack to equilibrium", "s", 0.001, 3600.0),
    HARDWARE_ID_PARAM,
]


class EstimatorNode(Node):
    """Lamella-pack torque estimator (see module docstring)."""

    def __init__(self):
        super().__init__(NAME)

        self._cfg = declare_params(self, PARAMS)
        self._params = declare_model_params(self, default_preset("flexiforce_8"))
        self._cfg.update(declare_params(self, ADAPT_PARAMS))
        self._cfg.update(declare_params(self, UNCERTAINTY_PARAMS))
        self._torque_std = TorqueStd(error_model(self._cfg))
        self._estimator = AdaptiveEstimator(self._params, adapt_settings(self._cfg),
                                            max_gap_s=self._cfg["estimator.max_gap"])
        self._saved = ""
        self._skipped: dict[str, int] = {}
        self._accepted = 0
        self._accepted_at_last_diag = 0
        self._peers = PeerWatch(self, [Input("rig data", _RIG_STATE,
                                             self._cfg["estimator.input_timeout"],
                                             "can_bridge")])
        self._last_error = ""
        self._warn = LogThrottle(5.0)
        self._pub = self.create_publisher(_msg_type(), _CLUTCH_ESTIMATE,
                                          publisher_qos(_CLUTCH_ESTIMATE))
        # rig_state taken raw and read by a compiled CDR reader, the estimate written as
        # bytes: no message object per sample (nodes/convert.py CdrCodec)
        self._encode = EstimateEncoder(self._pub.msg_type).encode
        rig_codec = CdrCodec(_rig_state_type())
        self._decode = rig_codec.decode
        self._inputs = [rig_codec.names.index(name) for name in _INPUTS]
        self._published = 0
        self._until_publish = 0  # accepted estimates to skip before the next publish
        # The node clock's C handle: its get_now() is the node's time (ROS time, /clock with
        # use_sim_time) without a rclpy Time object per sample.
        self._clock_handle = self.get_clock().handle
        # rig_state's subscriber QoS (best effort, which matches the bridge's reliable
        # publisher), with a deep queue so a stall of the estimator does not overwrite
        # samples; samples lost anyway are counted exactly from the DDS sequence numbers.
        self._loss = LossTracker()
        self._loss.add_topic(_RIG_STATE)
        self._sub = self.create_subscription(
            _rig_state_type(), _RIG_STATE, self._on_rig_state,
            subscriber_qos(_RIG_STATE, depth=self._cfg["estimator.queue_depth"]), raw=True)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._diag = Diagnostics(self, self._diagnose)
        self.get_logger().info(f"estimating with spline law '{self._params.spline.law}', "
                               f"{self._params.pack.lamella_count} lamellas")

    def _on_rig_state(self, msg: bytes, info) -> None:
        """Estimate ``msg`` (serialised), then the samples queued behind it (``DRAIN_MAX``).

        Taking the queued samples here, as rclpy's executor would (``take_message`` on the
        subscription handle), skips one executor iteration per sample, which costs more than
        the estimate; the bound lets timers and parameter services run during a flood.
        """
        self._on_sample(msg, info)
        handle, msg_type = self._sub.handle, self._sub.msg_type
        with handle:
            for _ in range(DRAIN_MAX):
                taken = handle.take_message(msg_type, True)
                if taken is None:
                    return
                self._on_sample(*taken)

    def _on_sample(self, msg: bytes, info) -> None:
        lost = self._loss.received(_RIG_STATE, info)
        if lost:
            self._skip("lost_in_transport", f"{lost} rig_state samples lost before this one",
                       count=lost)
        try:
            self._estimate(msg)
        except Exception as err:  # noqa: BLE001 - never die on one sample; diagnose it
            if not self.context.ok():  # a signal ended the context mid-sample: no fault
                return
            self._skip("internal_error", f"{type(err).__name__}: {err}")

    def _estimate(self, raw: bytes) -> None:
        now = self._clock_handle.get_now().nanoseconds * 1e-9  # [s] node clock
        self._peers.seen("rig data", now)
        values = self._decode(raw)
        sec, nanosec, frame_id, pressure, temperature, slip, torque, has_torque = (
            values[i] for i in self._inputs)
        stamp = interfaces.stamp_to_s(sec, nanosec)
        max_age = self._cfg["estimator.max_sample_age"]
        if max_age > 0.0 and now - stamp > max_age:
            self._skip("stale", f"sample {now - stamp:.3f} s old (> {max_age} s)")
            return
        measured = torque if has_torque else math.nan
        try:
            res = self._estimator.update(stamp, pressure, temperature, slip, measured)
        except SampleRejected as err:
            self._skip(type(err).__name__, str(err))
            return
        est = res.estimate
        if not math.isfinite(est.modelled_torque):  # defence in depth: never publish NaN
            self._skip("non_finite_output", "model produced a non-finite torque")
            return
        self._accepted += 1
        std = self._torque_std.update(stamp, est.modelled_torque, est.slip_speed_filtered,
                                      measured)
        if self._until_publish:  # decimated (estimator.publish_every): not this one
            self._until_publish -= 1
            return
        self._until_publish = self._cfg["estimator.publish_every"] - 1
        self._pub.publish(self._encode(est, res.adaptation, sec, nanosec, frame_id, std))
        self._published += 1

    def _skip(self, kind: str, why: str, count: int = 1) -> None:
        self._skipped[kind] = self._skipped.get(kind, 0) + count
        self._last_error = why
        if self._warn.ready():  # see LogThrottle: cheap when throttled
            self.get_logger().warning(f"skipped sample ({kind}): {why} (counts on "
                                      "/diagnostics)")

    def _on_set_parameters(self, params) -> SetParametersResult:
        own = {p.name: p.value for p in params if p.name.startswith("estimator.")}
        every = own.get("estimator.publish_every", 1)
        if isinstance(every, bool) or not isinstance(every, int) or every < 1:
            return SetParametersResult(successful=False, reason="estimator.publish_every "
                                       f"must be an integer >= 1, got {every!r}")
        # Validated against the complete current set (required keys included).
        new_params, reason = apply_model_changes(self._params, params)
        if reason:
            return SetParametersResult(successful=False, reason=reason)
        adapt = {p.name: p.value for p in params if p.name.startswith("adapt.")}
        settings = None
        if set(adapt) - {"adapt.save_params_file"}:
            try:
                settings = adapt_settings({**self._cfg, **adapt})
            except ClutchError as err:
                return SetParametersResult(successful=False, reason=str(err))
        target = adapt.get("adapt.save_params_file", "")
        if target:
            try:  # written now, so a refused write leaves the parameter unchanged
                save_adapted_params(target, self._estimator, "the live estimator node")
            except (ClutchError, OSError) as err:
                return SetParametersResult(successful=False, reason=str(err))
            self._saved = target
            self.get_logger().info(f"adapted parameters written to {target} (friction scale "
                                   f"{self._estimator.friction_scale:.4f})")
        if new_params is not None:
            self._estimator.set_base_params(new_params)
            self._params = new_params
        if settings is not None:
            self._estimator.set_settings(settings)
        self._cfg.update(own)
        self._until_publish = min(self._until_publish, self._cfg["estimator.publish_every"] - 1)
        self._cfg.update(adapt)
        if "estimator.max_gap" in own:
            self._estimator.estimator.max_gap_s = own["estimator.max_gap"]
        if "estimator.input_timeout" in own:
            self._peers.set_timeout("rig data", own["estimator.input_timeout"])
        return SetParametersResult(successful=True)

    def _diagnose(self):
        now = self.get_clock().now().nanoseconds * 1e-9
        rate = float(self._accepted - self._accepted_at_last_diag)
        self._accepted_at_last_diag = self._accepted
        values = {"accepted": self._accepted, "published": self._published,
                  "publish_every": self._cfg["estimator.publish_every"], "input_rate_hz": rate,
                  "spline_law": self._params.spline.law, "last_error": self._last_error}
        values.update({f"skipped_{k}": v for k, v in self._skipped.items()})
        values.update(self._peers.ages(now))
        ae = self._estimator
        status = ae.status
        values.update(friction_scale=ae.friction_scale,
                      friction_scale_std=status.friction_scale_std,
                      spline_gain_scale=ae.spline_gain_scale, adaptation_state=status.state,
                      adaptation_reason=status.reason, adaptation_saved_to=self._saved,
                      **{f"adaptation_{k}": v for k, v in ae.counts.items()})
        silent = self._peers.silent(now)
        if silent:
            return "WARN", silent, values
        if status.state == "frozen":
            return "WARN", f"adaptation frozen: {status.reason}", values
        if self._skipped:
            return "OK", f"running; skipped {sum(self._skipped.values())} samples", values
        return "OK", "running", values


def _msg_type():

    return ClutchEstimate


def _rig_state_type():

    return RigState


def main(args=None) -> int:
    """Console entry point: ``ros2 run clutch_ros estimator``."""
    return run_node(NAME, __doc__, PARAMS + ADAPT_PARAMS + _model_specs_for_help(),
                    EstimatorNode, args)


def _model_specs_for_help():
    try:
        return model_param_specs(defaults=load_flat(default_preset("flexiforce_8")))
    except Exception:  # noqa: BLE001 - help must work even with a broken preset
        return []


if __name__ == "__main__":
    raise SystemExit(main())
