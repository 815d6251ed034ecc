"""The ``--adapt`` options of ``clutch replay``: online adaptation over the bags, and saving it.

``--adapt`` runs the adaptive estimator (:mod:`clutch_ros.model.adaptation`) through the
bags in the order given, one estimator for all of them, as a rig PC that records run after
run (:mod:`clutch_ros.offline.adapt`); each bag's JSON object gains ``friction_scale``,
``friction_scale_std``, ``spline_gain_scale``, ``spline_gain_scale_std``, ``adaptation``
(samples per state) and ``events`` (every freeze and resume with its reason), and its
``rmse_nm`` is the adaptive estimate's. ``--save-params FILE`` writes the adapted parameters
(after the last bag) as a complete parameter file the nodes and every subcommand accept.
"""

from __future__ import annotations

import sys
from pathlib import Path

from clutch_ros.errors import ClutchError
from clutch_ros.model.adaptation import AdaptationSettings, AdaptiveEstimator
from clutch_ros.offline.adapt import (
    adaptive_replay,
    save_adapted_params,
    write_adaptive_estimates,
)

__all__ = ["AdaptiveRun", "add_adapt_options", "print_adaptation"]


def add_adapt_options(p) -> None:
    """Register ``--adapt``, ``--save-params``, ``--adapt-spline-gain``, ``--forgetting-time``."""
    g = p.add_argument_group("online adaptation")
    g.add_argument("--adapt", action="store_true",
                   help="adapt the friction scale (a multiplier of mu) online from the "
                        "measured torque, through the bags in the order given")
    g.add_argument("--save-params", metavar="FILE",
                   help="with --adapt: write the adapted parameters (complete parameter "
                        "file) after the last bag")
    g.add_argument("--adapt-spline-gain", action="store_true",
                   help="with --adapt: also adapt spline.gain (ff_t and ff_v laws only)")
    g.add_argument("--forgetting-time", type=float, default=AdaptationSettings.forgetting_time,
                   metavar="S", help="with --adapt: memory of the adaptation [s] (default "
                   f"{AdaptationSettings.forgetting_time:g})")


class AdaptiveRun:
    """The adaptive side of one ``clutch replay`` call (None-safe: off without --adapt)."""

    def __init__(self, args, params):
        adapt_only = [name for name, given in (
            ("--save-params", args.save_params), ("--adapt-spline-gain",
                                                  args.adapt_spline_gain)) if given]
        if adapt_only and not args.adapt:
            raise ClutchError(f"{', '.join(adapt_only)} needs --adapt")
        self.enabled = bool(args.adapt)
        self.save_to = Path(args.save_params) if args.save_params else None
        if self.save_to is not None and self.save_to.is_dir():
            raise ClutchError(f"--save-params {self.save_to}: is a directory")
        self.bags: list[str] = []
        self.estimator: AdaptiveEstimator | None = None  # with --adapt
        if self.enabled:
            try:
                settings = AdaptationSettings(spline_gain=args.adapt_spline_gain,
                                              forgetting_time=args.forgetting_time)
            except ClutchError as err:
                raise ClutchError(f"--forgetting-time: {err}") from None
            self.estimator = AdaptiveEstimator(params, settings)

    def replay(self, bag, topic=None):
        """Replay one bag adaptively; return ``(ReplayResult, writer(out, storage))``."""
        assert self.estimator is not None  # called with --adapt only
        run = adaptive_replay([bag], self.estimator.base_params, estimator=self.estimator,
                              topic=topic)[0]
        self.bags.append(Path(bag).name)

        def write(out, storage):
            return write_adaptive_estimates(out, run, storage=storage)
        return run.result, write

    def finish(self) -> str | None:
        """Save the adapted parameters when asked; return the file written (or None)."""
        if self.save_to is None or self.estimator is None:  # (--save-params needs --adapt)
            return None
        save_adapted_params(self.save_to, self.estimator, ", ".join(self.bags))
        return str(self.save_to)


def print_adaptation(summary: dict) -> None:
    """Write the human line of one bag's adaptation to stdout."""
    events = summary.get("events", [])
    frozen = [e for e in events if e["state"] == "frozen"]
    sys.stdout.write(
        f"  adapted friction scale {summary['friction_scale']:.4f} +- "
        f"{summary['friction_scale_std']:.4f}, spline gain scale "
        f"{summary['spline_gain_scale']:.4f}; adapting {summary['adaptation']['adapting']} "
        f"of {summary['accepted']} samples"
        + (f"; frozen {len(frozen)}x (first: {frozen[0]['reason']})" if frozen else "")
        + "\n")
