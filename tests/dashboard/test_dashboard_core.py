"""The dashboard core without a client: schema text, layout, errors, diagnostics encoding."""

import json
import re

import pytest
from rosbags.rosbag2 import Reader

from clutch_ros.bag.typestore import clutch_typestore
from clutch_ros.bag.writer import BagWriter
from clutch_ros.config.params_file import load_params
from clutch_ros.config.presets import params_dir, preset_path
from clutch_ros.dashboard import (
    TOPICS,
    BagPlayer,
    BagStream,
    DashboardError,
    DashboardServer,
    diagnostic_array_cdr,
    message_definition,
)
from tests.conftest import REPO

GOLDEN = REPO / "tests/data/golden/bags/table3_seq1_10rpm"


def test_schema_text_is_what_the_bags_mcap_stores():
    with Reader(GOLDEN) as reader:
        conn = next(c for c in reader.connections if c.topic == "/rig_state")
        stored = conn.msgdef.data
    assert message_definition("clutch_msgs/msg/RigState") == stored


def test_every_served_type_has_a_definition_with_dependencies():
    for topic in TOPICS:
        text = message_definition(topic.typename)
        assert "\n" + "=" * 80 + "\nMSG: std_msgs/Header\n" in text, topic.typename


def test_layout_plots_only_fields_that_exist():
    layout = json.loads((params_dir() / "clutch_dashboard.json").read_text())
    store = clutch_typestore()
    types = {f"/{t.name.strip('/')}": t.typename for t in TOPICS}
    seen = set()
    for panel, cfg in layout["configById"].items():
        for path in cfg.get("paths", []):
            topic, field = path["value"].split(".", 1)
            seen.add(topic)
            if topic.startswith("/studio_script/"):
                assert topic.endswith("accuracy_band") and field in ("upper", "lower")
                continue
            fields = dict(store.fielddefs[types[topic]][1])
            assert re.sub(r"\[\d+\]$", "", field) in fields, (panel, path["value"])
    assert {"/clutch_estimate", "/rig_state", "/torque_request", "/pressure_command",
            "/pump_request"} <= seen
    assert any(p.startswith("DiagnosticSummary") for p in layout["configById"])


def test_busy_port_is_a_clear_error():
    with DashboardServer(port=0) as first:
        with pytest.raises(DashboardError, match=f"cannot serve on 127.0.0.1:{first.port}"):
            DashboardServer(port=first.port)


def test_bad_rate_and_bag_without_served_topics(tmp_path):
    params = load_params(preset_path("flexiforce_8"))
    stream = BagStream(GOLDEN, params)
    with DashboardServer(port=0) as server:
        for rate in (0.0, -1.0, 1e6):
            with pytest.raises(DashboardError, match="playback rate"):
                BagPlayer(stream, server, rate=rate)
    bag = tmp_path / "other"
    with BagWriter(bag) as writer:
        topic = writer.add_topic("/elsewhere", "clutch_msgs/msg/TorqueRequest")
        from clutch_ros.bag.typestore import torque_request_msg

        writer.write(topic, 1, torque_request_msg(1, 5.0))
    with pytest.raises(DashboardError, match="no topic the dashboard serves"):
        BagStream(bag, params)


def test_diagnostic_array_round_trip():
    data = diagnostic_array_cdr(1_700_000_000_123_000_000, "/dashboard", "WARN", "slow",
                                {"clients": 2, "lag_s": 0.25})
    msg = clutch_typestore().deserialize_cdr(data, "diagnostic_msgs/msg/DiagnosticArray")
    status = msg.status[0]
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1_700_000_000, 123_000_000)
    assert (status.level, status.name, status.message) == (1, "/dashboard", "slow")
    assert {kv.key: kv.value for kv in status.values} == {"clients": "2", "lag_s": "0.25"}
