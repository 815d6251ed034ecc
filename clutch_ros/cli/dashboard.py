"""``clutch dashboard``: the clutch topics on a Foxglove WebSocket server, live or from a bag.

Without ``--bag`` it runs the live ``dashboard`` node (:mod:`clutch_ros.nodes.dashboard`):
every clutch topic of this ROS domain is forwarded as the CDR bytes ROS delivers. With
``--bag BAG`` it plays the bag in real time × ``--rate``; when the bag holds RigState but no
ClutchEstimate, the estimates are computed on the fly with the estimator's model (``--params``,
``--law``), exactly as ``clutch replay -o`` writes them. Open ``ws://HOST:PORT`` in Foxglove
(open connection -> Foxglove WebSocket) and import ``params/clutch_dashboard.json`` as the
layout (README.md). Ctrl-C stops.

In ``--bag`` mode the server's time is the bag's time and clients control the playback
(pause, resume, seek, speed); at the end it waits for a seek (``--exit-at-end``: exits). The
estimator parameters the estimates were computed with are shown read-only as
``/estimator.*``. Live, ``--allow-publish`` lets clients publish on ``torque_request`` only.
"""

from __future__ import annotations

import signal
import sys
from pathlib import Path

from clutch_ros.config.params_file import load_params
from clutch_ros.config.presets import preset_path
from clutch_ros.dashboard import BagPlayer, BagStream, DashboardServer
from clutch_ros.dashboard.parameters import ReadOnlyParameters
from clutch_ros.dashboard.playback import MAX_SPEED, PlaybackClock
from clutch_ros.errors import ClutchError
from clutch_ros.model.params import PASSIVE_LAWS

__all__ = ["add_parser", "run"]


def add_parser(sub) -> None:
    """Register ``clutch dashboard``."""
    p = sub.add_parser("dashboard", help="serve the clutch topics to Foxglove (live or a bag)",
                       description=__doc__.split("\n\n")[0])
    p.add_argument("--bag", metavar="BAG", help="play this bag instead of the live topics")
    p.add_argument("--rate", type=float, default=None,
                   help="playback speed of --bag, a factor of real time (default 1)")
    p.add_argument("--loop", action="store_true", help="play --bag over and over")
    p.add_argument("--exit-at-end", action="store_true",
                   help="exit at the end of --bag (default: wait for a client to seek)")
    p.add_argument("--allow-publish", action="store_true",
                   help="live: let clients publish TorqueRequest on torque_request (only)")
    p.add_argument("--port", type=int, default=8765,
                   help="TCP port of the WebSocket server (default 8765; 0: any free port)")
    p.add_argument("--host", default="127.0.0.1",
                   help="bind address (default 127.0.0.1; 0.0.0.0 serves every interface)")
    p.add_argument("--backlog", type=int, default=1024,
                   help="messages queued per client before its oldest are dropped "
                        "(default 1024)")
    p.add_argument("--params", default="flexiforce_8",
                   help="estimator parameter preset or YAML file for --bag estimates "
                        "(default: flexiforce_8, the estimator node's)")
    p.add_argument("--law", choices=tuple(PASSIVE_LAWS),
                   help="override spline.law of --params (as clutch replay --law)")
    p.add_argument("--json", action="store_true",
                   help="print a JSON summary of the playback on stdout at the end")
    p.set_defaults(func=run)


def _say(text: str) -> None:
    sys.stderr.write(text + "\n")
    sys.stderr.flush()


def run(args) -> int:
    """Serve live (the node) or a bag; return the exit code."""
    if not 0 <= args.port <= 65535:
        raise ClutchError(f"--port {args.port} is not a TCP port (0..65535)")
    if args.backlog < 1:
        raise ClutchError(f"--backlog must be at least 1 message, got {args.backlog}")
    if args.bag is None:
        if args.rate is not None or args.loop or args.exit_at_end:
            raise ClutchError("--rate, --loop and --exit-at-end apply to --bag playback only")
        return _live(args)
    if args.allow_publish:
        raise ClutchError("--allow-publish applies to the live topics only (not --bag)")
    return _bag(args)


def _live(args) -> int:
    from clutch_ros.nodes.dashboard import main as node_main  # rclpy only in live mode

    return node_main(["--ros-args", "-p", f"dashboard.port:={args.port}",
                      "-p", f"dashboard.address:={args.host}",
                      "-p", f"dashboard.message_backlog:={args.backlog}",
                      "-p", f"dashboard.allow_publish:={str(args.allow_publish).lower()}"])


def _bag(args) -> int:

    rate = 1.0 if args.rate is None else args.rate
    if not 0.0 < rate <= MAX_SPEED:
        raise ClutchError(f"--rate must be in (0, {MAX_SPEED:g}], got {rate}")
    bag = Path(args.bag)
    params = load_params(preset_path(args.params))
    if args.law:
        params = params.with_law(args.law)
    stream = BagStream(bag, params)
    clock = PlaybackClock(stream.start_ns, stream.end_ns, rate)
    shown = ReadOnlyParameters("/estimator", params.to_flat(),
                               f"the estimates of {bag.name} were computed with --params "
                               f"{args.params} before playback; change --params and restart")
    with DashboardServer(args.host, args.port, backlog=args.backlog, serve_time=True,
                         playback_range=(stream.start_ns, stream.end_ns), playback=clock,
                         parameters=shown) as server:
        player = BagPlayer(stream, server, loop=args.loop, clock=clock,
                           exit_at_end=args.exit_at_end)
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, lambda *_: player.stop())
        what = ", ".join(f"{t} ({n})" for t, n in stream.counts.items())
        computed = "; estimates computed with spline law " + params.spline.law \
            if stream.computed else ""
        _say(f"clutch dashboard: serving {bag} on {server.url} at {rate:g}x real time: "
             f"{what}{computed}")
        summary = player.run()
        level, message, values = server.status()
    summary.update(bag=str(bag), url=values["url"], rate=rate, computed=stream.computed,
                   law=params.spline.law if stream.computed else None,
                   connections=values["connections"],
                   outbox_full_events=values["outbox_full_events"], status=message)
    if args.json:
        from clutch_ros.cli.dispatch import emit_json

        emit_json(summary)
    else:
        _say(f"clutch dashboard: {summary['published']} messages played"
             f"{' (stopped)' if summary['stopped'] else ''}; {message}")
    return 0
