"""Second process of the udp_multicast test: a rig that sends fuzz traffic, then a pump ECU.

Usage: ``python udp_peer.py GROUP PORT SEED COUNT RATE EXPECT``. Opens the multicast bus,
prints ``ready``, sends ``COUNT`` fuzz frames (fuzzgen, ``SEED``) paced at ``RATE`` frames/s,
then collects ``EXPECT`` PumpRequest frames (10 s at most) and prints them as one JSON line:
``[[pressure_pa, counter, checksum_ok], ...]``.
"""

import json
import sys
import time
from pathlib import Path

import can

sys.path.insert(0, str(Path(__file__).resolve().parent))

from fuzzgen import generate  # noqa: E402

from clutch_ros.canbus.dbc import RigDatabase
from clutch_ros.canbus.pump_codec import PumpRequestCodec  # noqa: E402


def main() -> int:
    group, port, seed, count, rate, expect = sys.argv[1:7]
    db = RigDatabase()
    codec = PumpRequestCodec(db)
    frames, _ = generate(int(seed), int(count), db)
    with can.Bus(interface="udp_multicast", channel=group, port=int(port), fd=True) as bus:
        print("ready", flush=True)
        start = time.perf_counter()
        for i, msg in enumerate(frames):
            delay = start + i / float(rate) - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
            bus.send(msg)
        received = []
        deadline = time.monotonic() + 10.0
        while len(received) < int(expect) and time.monotonic() < deadline:
            msg = bus.recv(0.1)
            if msg is not None and msg.arbitration_id == codec.spec.frame_id:
                received.append(list(codec.decode(msg)))
        print(json.dumps(received), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
