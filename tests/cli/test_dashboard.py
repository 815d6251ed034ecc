"""``clutch dashboard --bag``: a Foxglove WebSocket client of our own against the real command.

The command runs in a subprocess on a free port, playing a golden bag (RigState only, so the
estimates are computed on the fly) at 8x real time in a loop, with a 64-message queue per
client. The client (``tests/dashboard/foxglove_client.py``, the ``websockets`` library
speaking the protocol, not foxglove-sdk) checks the advertised channels, subscribes, decodes
the payloads with rosbags from the advertised ``ros2msg`` schema text, and compares every
ClutchEstimate with ``clutch replay -o`` of the same bag at the same header stamp (decoded
modelled torque and the whole CDR payload). A second client connects later and must receive
messages too; a third stops reading (small receive buffer, never reads) until its queue
overflows, which ``/diagnostics`` must report: the first client's message rate while the
third one's messages are being dropped must stay within 10 % of its rate before.
"""

import asyncio
import re
import socket
import subprocess
import sys
import threading
import time

import pytest

from clutch_ros.bag.reader import BagReader
from tests.conftest import REPO
from tests.dashboard.foxglove_client import FoxgloveClient

BAG = REPO / "tests/data/golden/bags/table3_seq1_10rpm"
RATE = 8.0
TOPICS = ["/rig_state", "/clutch_estimate", "/diagnostics"]
SERVED = {
    "/rig_state": "clutch_msgs/msg/RigState",
    "/clutch_estimate": "clutch_msgs/msg/ClutchEstimate",
    "/torque_request": "clutch_msgs/msg/TorqueRequest",
    "/pressure_command": "clutch_msgs/msg/PressureCommand",
    "/pump_request": "clutch_msgs/msg/PressureCommand",
    "/can_frames": "clutch_msgs/msg/CanFrame",  # every clutch topic (issue 25)
    "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
}


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@pytest.fixture(scope="module")
def replayed(tmp_path_factory):
    """``clutch replay -o`` of the bag: header stamp [ns] -> (modelled torque, CDR bytes)."""
    out = tmp_path_factory.mktemp("dash") / "estimates"
    subprocess.run([sys.executable, "-m", "clutch_ros.cli", "replay", str(BAG), "--params",
                    "flexiforce_8", "-o", str(out)], check=True, cwd=REPO, timeout=120,
                   capture_output=True)
    ref = {}
    with BagReader(out) as bag:
        for raw, msg in zip(bag.messages("/clutch_estimate", raw=True),
                            bag.messages("/clutch_estimate")):
            stamp = msg.msg.header.stamp.sec * 1_000_000_000 + msg.msg.header.stamp.nanosec
            ref[stamp] = (msg.msg.modelled_torque, bytes(raw.msg))
    assert len(ref) > 1000
    return ref


@pytest.fixture(scope="module")
def server():
    """Run the command in a subprocess; yield its ws:// URL and collects its stderr."""
    port = free_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "clutch_ros.cli", "dashboard", "--bag", str(BAG), "--rate",
         str(RATE), "--loop", "--port", str(port), "--backlog", "64"],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines: list[str] = []
    ready = threading.Event()

    def pump():
        for line in proc.stderr:
            lines.append(line)
            if "serving" in line:
                ready.set()

    threading.Thread(target=pump, daemon=True).start()
    assert ready.wait(60), "".join(lines)
    url = re.search(r"ws://\S+", "".join(lines)).group(0)
    assert url == f"ws://127.0.0.1:{port}"
    yield url
    proc.send_signal(2)  # SIGINT: the player stops, the server closes, exit 0
    out, _ = proc.communicate(timeout=20)
    assert proc.returncode == 0, "".join(lines)


async def scenario(url):
    """Client A throughout; B joins later; C joins with B and never reads."""
    a = FoxgloveClient(url)
    await a.connect()
    await a.subscribe(TOPICS)
    await a.read_for(1.0)  # settle
    t0 = time.monotonic()
    await a.read_for(3.0)
    t1 = time.monotonic()
    b, c = FoxgloveClient(url), FoxgloveClient(url, rcvbuf=4096)
    await asyncio.gather(b.connect(), c.connect(), a.read_for(0.5))
    await asyncio.gather(b.subscribe(TOPICS), c.subscribe(TOPICS[:2]))
    # C's socket buffers fill up first (about 2.8 MB here), then its 64-message queue
    # overflows: wait for /diagnostics to say so, then measure.
    deadline = time.monotonic() + 60.0
    while overflow_events(a) < 1 and time.monotonic() < deadline:
        await asyncio.gather(a.read_for(1.0), b.read_for(1.0))
    await asyncio.gather(a.read_for(0.5), b.read_for(0.5))
    t2 = time.monotonic()
    await asyncio.gather(a.read_for(4.0), b.read_for(4.0))
    t3 = time.monotonic()
    for client in (a, b, c):
        await client.close()
    return a, b, (t0, t1, t2, t3)


def diagnostics(client) -> list[dict]:
    """Return the dashboard's /diagnostics status values received by ``client``, in order."""
    values = []
    for _, _, data in client.messages["/diagnostics"]:
        status = client.decode("/diagnostics", data).status[0]
        values.append({kv.key: kv.value for kv in status.values} | {"level": status.level})
    return values


def overflow_events(client) -> int:
    """Return the latest ``outbox_full_events`` reported (0 before any report)."""
    values = diagnostics(client)
    return int(values[-1]["outbox_full_events"]) if values else 0


@pytest.fixture(scope="module")
def clients(server):
    return asyncio.run(scenario(server))


def test_channels_are_advertised_with_ros2msg_schemas(clients):
    a, _, _ = clients
    assert {t: ch["schemaName"] for t, ch in a.channels.items()} == SERVED
    for topic, channel in a.channels.items():
        assert channel["encoding"] == "cdr", topic
        assert channel["schemaEncoding"] == "ros2msg", topic
    # The definition with its dependencies, as rosbag2's MCAP storage writes it.
    schema = a.channels["/clutch_estimate"]["schema"]
    assert "\nMSG: std_msgs/Header\n" in schema and "\nMSG: builtin_interfaces/Time\n" in schema
    assert schema.splitlines()[0] == "std_msgs/Header header"


def test_estimates_equal_clutch_replay(clients, replayed):
    a, _, _ = clients
    assert len(a.messages["/rig_state"]) >= 100
    assert len(a.messages["/clutch_estimate"]) >= 100
    rig_stamps = set()
    for _, _, data in a.messages["/rig_state"]:
        msg = a.decode("/rig_state", data)
        rig_stamps.add(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)
    matched = 0
    for _, _, data in a.messages["/clutch_estimate"]:
        msg = a.decode("/clutch_estimate", data)
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        torque, raw = replayed[stamp]
        assert msg.modelled_torque == torque  # exactly: the same model, the same bytes
        assert data == raw
        matched += stamp in rig_stamps
    assert matched >= 100  # estimates belong to the RigState samples served alongside


def test_late_client_receives(clients):
    _, b, _ = clients
    for topic in TOPICS[:2]:
        assert len(b.messages[topic]) >= 100, topic
    b.decode("/clutch_estimate", b.messages["/clutch_estimate"][-1][2])


def test_stalled_client_does_not_slow_the_others(clients):
    a, b, (t0, t1, t2, t3) = clients
    before = a.rate(TOPICS[:2], t0, t1)
    during = a.rate(TOPICS[:2], t2, t3)
    late = b.rate(TOPICS[:2], t2, t3)
    expected = 200.0 * RATE  # 100 Hz RigState + 100 Hz ClutchEstimate, x RATE
    sys.stderr.write(f"client A {before:.1f} msg/s before the stall, {during:.1f} during; "
                     f"client B {late:.1f}; schedule {expected:.0f}\n")
    assert abs(during / before - 1.0) <= 0.10
    assert abs(late / before - 1.0) <= 0.10
    assert before > 0.8 * expected  # the player kept its schedule at all


def test_overflow_reported_on_diagnostics(clients):
    a, _, _ = clients
    values = diagnostics(a)
    assert values and values[0]["message_backlog"] == "64"
    last = values[-1]
    assert int(last["clients"]) == 3 and int(last["connections"]) == 3
    assert int(last["outbox_full_events"]) >= 1, last
    assert last["level"] == 1  # WARN: a client lost messages
    assert int(last["forwarded_clutch_estimate"]) > 0
