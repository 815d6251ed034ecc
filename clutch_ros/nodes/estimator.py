"""The ``estimator`` node: RigState in, ClutchEstimate out, one per accepted sample.

Runs the model core's :class:`clutch_ros.model.ClutchEstimator` (lamella pack + spline-friction
law) on every ``rig_state`` sample, using the message stamps for time (never wall time), so a
bag replayed at any speed gives the same estimates. Samples that are NaN/inf, out of order,
duplicated or older than ``estimator.max_sample_age`` are skipped, counted and reported on
``/diagnostics``; a NaN torque is never published. Model parameters are the DESIGN.md keys
(``clutch.*``, ``friction.*``, ``spline.*``, ``slip.*``); runtime changes are validated by the
model and rejected with its reason (their ranges are the model's, stated in the descriptors'
``additional_constraints``), and applied without losing the pack state.
"""

from __future__ import annotations

import math

from clutch_msgs.msg import ClutchEstimate, RigState
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy

from clutch_ros.config.params_file import load_flat
from clutch_ros.config.presets import default_preset
from clutch_ros.model import ClutchEstimator, SampleRejected
from clutch_ros.nodes.common import (
    HARDWARE_ID_PARAM,
    Diagnostics,
    LogThrottle,
    ParamSpec,
    declare_params,
    reliable_qos,
    run_node,
    stamp_to_sec,
)
from clutch_ros.nodes.convert import estimate_to_msg
from clutch_ros.nodes.loss_tracker import LossTracker
from clutch_ros.nodes.model_params import (
    apply_model_changes,
    declare_model_params,
    model_param_specs,
)
from clutch_ros.nodes.peers import Input, PeerWatch

NAME = "estimator"
PARAMS = [
    ParamSpec("estimator.max_sample_age", 0.5, "skip samples whose stamp is older than this "
              "relative to the node clock; 0 disables the check", "s", 0.0, 3600.0),
    ParamSpec("estimator.input_timeout", 0.5, "no input for longer than this is reported as "
              "stale on /diagnostics", "s", 0.001, 3600.0),
    ParamSpec("estimator.queue_depth", 200, "rig_state subscription queue (sensor-data QoS, "
              "best effort); samples lost anyway are counted; read-only: a DDS reader's "
              "history depth is fixed when the subscription is created", "messages", 1, 100000,
              read_only=True),
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
        self._estimator = ClutchEstimator(self._params,
                                          max_gap_s=self._cfg["estimator.max_gap"])
        self._skipped: dict[str, int] = {}
        self._accepted = 0
        self._accepted_at_last_diag = 0
        self._peers = PeerWatch(self, [Input("rig data", "rig_state",
                                             self._cfg["estimator.input_timeout"],
                                             "can_bridge")])
        self._last_error = ""
        self._warn = LogThrottle(5.0)
        self._pub = self.create_publisher(_msg_type(), "clutch_estimate", reliable_qos())
        # Sensor-data QoS (best effort) as the bridge offers it, with a deep queue so a
        # stall of the estimator does not overwrite samples; samples lost anyway are counted
        # exactly from the DDS publication sequence numbers.


        self._loss = LossTracker()
        self._loss.add_topic("rig_state")
        self.create_subscription(_rig_state_type(), "rig_state", self._on_rig_state,
                                 QoSProfile(depth=self._cfg["estimator.queue_depth"],
                                            reliability=ReliabilityPolicy.BEST_EFFORT))
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._diag = Diagnostics(self, self._diagnose)
        self.get_logger().info(f"estimating with spline law '{self._params.spline.law}', "
                               f"{self._params.pack.lamella_count} lamellas")

    def _on_rig_state(self, msg, info) -> None:
        lost = self._loss.received("rig_state", info)
        if lost:
            self._skip("lost_in_transport", f"{lost} rig_state samples lost before this one",
                       count=lost)
        try:
            self._estimate(msg)
        except Exception as err:  # noqa: BLE001 - never die on one sample; diagnose it
            self._skip("internal_error", f"{type(err).__name__}: {err}")

    def _estimate(self, msg) -> None:

        now = self.get_clock().now().nanoseconds * 1e-9
        self._peers.seen("rig data", now)
        stamp = stamp_to_sec(msg.header.stamp)
        max_age = self._cfg["estimator.max_sample_age"]
        if max_age > 0.0 and now - stamp > max_age:
            self._skip("stale", f"sample {now - stamp:.3f} s old (> {max_age} s)")
            return
        measured = msg.measured_torque if msg.has_measured_torque else math.nan
        try:
            est = self._estimator.update(stamp, msg.actuating_pressure, msg.lamella_temperature,
                                         msg.slip_speed, measured)
        except SampleRejected as err:
            self._skip(type(err).__name__, str(err))
            return
        if not math.isfinite(est.modelled_torque):  # defence in depth: never publish NaN
            self._skip("non_finite_output", "model produced a non-finite torque")
            return
        self._accepted += 1
        self._pub.publish(estimate_to_msg(est, msg.header, self._pub.msg_type))

    def _skip(self, kind: str, why: str, count: int = 1) -> None:
        self._skipped[kind] = self._skipped.get(kind, 0) + count
        self._last_error = why
        if self._warn.ready():  # see LogThrottle: cheap when throttled
            self.get_logger().warning(f"skipped sample ({kind}): {why} (counts on "
                                      "/diagnostics)")

    def _on_set_parameters(self, params) -> SetParametersResult:

        # Validated against the complete current set (required keys included).
        new_params, reason = apply_model_changes(self._params, params)
        if reason:
            return SetParametersResult(successful=False, reason=reason)
        if new_params is not None:
            self._estimator.set_params(new_params)
            self._params = new_params
        own = {p.name: p.value for p in params if p.name.startswith("estimator.")}
        self._cfg.update(own)
        if "estimator.max_gap" in own:
            self._estimator.max_gap_s = own["estimator.max_gap"]
        if "estimator.input_timeout" in own:
            self._peers.set_timeout("rig data", own["estimator.input_timeout"])
        return SetParametersResult(successful=True)

    def _diagnose(self):
        now = self.get_clock().now().nanoseconds * 1e-9
        rate = float(self._accepted - self._accepted_at_last_diag)
        self._accepted_at_last_diag = self._accepted
        values = {"accepted": self._accepted, "input_rate_hz": rate,
                  "spline_law": self._params.spline.law, "last_error": self._last_error}
        values.update({f"skipped_{k}": v for k, v in self._skipped.items()})
        values.update(self._peers.ages(now))
        silent = self._peers.silent(now)
        if silent:
            return "WARN", silent, values
        if self._skipped:
            return "OK", f"running; skipped {sum(self._skipped.values())} samples", values
        return "OK", "running", values


def _msg_type():

    return ClutchEstimate


def _rig_state_type():

    return RigState


def main(args=None) -> int:
    """Console entry point: ``ros2 run clutch_ros estimator``."""
    return run_node(NAME, __doc__, PARAMS + _model_specs_for_help(), EstimatorNode, args)


def _model_specs_for_help():
    try:
        return model_param_specs(defaults=load_flat(default_preset("flexiforce_8")))
    except Exception:  # noqa: BLE001 - help must work even with a broken preset
        return []


if __name__ == "__main__":
    raise SystemExit(main())
