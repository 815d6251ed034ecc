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
                assert topic.rsplit("/", 1)[1] in layout["userNodes"], path["value"]
                assert topic.endswith(("accuracy_band", "torque_band")), path["value"]
                assert field in ("upper", "lower"), path["value"]
                continue
            fields = dict(store.fielddefs[types[topic]][1])
            assert re.sub(r"\[\d+\]$", "", field) in fields, (panel, path["value"])
    assert {"/clutch_estimate", "/rig_state", "/torque_request", "/pressure_command",
            "/pump_request"} <= seen
    assert any(p.startswith("DiagnosticSummary") for p in layout["configById"])
    # the torque plot's 95 % band: modelled_torque +- 1.96 modelled_torque_std
    band = layout["userNodes"]["torque_band"]["sourceCode"]
    assert "1.96 * event.message.modelled_torque_std" in band
    assert '"/studio_script/torque_band"' in band
    torque = [p["value"] for p in layout["configById"]["Plot!torque"]["paths"]]
    assert {"/studio_script/torque_band.upper", "/studio_script/torque_band.lower"} <= set(torque)


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


def test_playback_clock_pause_speed_seek():
    from clutch_ros.dashboard import PlaybackClock

    wall = [100.0]
    clock = PlaybackClock(1_000, 10_000_000_000, 2.0, clock=lambda: wall[0])
    wall[0] += 1.0
    assert clock.now_ns() == 1_000 + 2_000_000_000  # 1 s at 2x
    report = clock.request(False, 2.0, None)
    assert (report.status, report.current_ns, report.did_seek) == ("paused", 2_000_001_000,
                                                                   False)
    wall[0] += 5.0
    assert clock.now_ns() == 2_000_001_000 and clock.due_wall(3_000_000_000) is None
    clock.request(True, 0.5, None)  # resume at half speed from where it paused
    assert clock.due_wall(2_500_001_000) == pytest.approx(wall[0] + 1.0)
    report = clock.request(True, 0.5, 99_000_000_000)  # clamped to the end
    assert report.did_seek and report.current_ns == 10_000_000_000
    assert clock.take_seek() == 10_000_000_000 and clock.take_seek() is None
    assert clock.mark_ended().status == "ended"
    assert clock.request(True, -1.0, 0).speed == 0.5  # a bad speed keeps the old one


def test_parameter_names_and_read_only_set():
    from clutch_ros.dashboard import ReadOnlyParameters, split_name

    assert split_name("/estimator.spline.law") == ("/estimator", "spline.law")
    assert split_name("/rig1/controller.controller.rate") == ("/rig1/controller",
                                                              "controller.rate")
    for bad in ("estimator.x", "/estimator", "/estimator.", "/.x"):
        with pytest.raises(DashboardError, match="is not /node.parameter"):
            split_name(bad)
    params = load_params(preset_path("flexiforce_8"))
    shown = ReadOnlyParameters("/estimator", params.to_flat(), "computed before playback")
    values = shown.get([])
    assert values["/estimator.spline.law"] == params.spline.law
    kept, refusals = shown.set({"/estimator.spline.law": "none", "/estimator.nope": 1})
    assert kept == {"/estimator.spline.law": params.spline.law}
    assert refusals == ["/estimator.spline.law: read-only: computed before playback",
                        "/estimator.nope: no such parameter"]


def test_publish_gate_admits_torque_requests_only():
    from clutch_ros.bag.typestore import torque_request_msg
    from clutch_ros.dashboard.client_publish import PublishGate

    got = []
    gate = PublishGate(lambda *a: got.append(a))
    typename = "clutch_msgs/msg/TorqueRequest"
    assert gate.advertise(1, 1, "/torque_request", "cdr", typename) is None
    assert gate.advertise(1, 2, "/torque_request", "json", typename) is None
    assert "only" in gate.advertise(1, 3, "/pressure_command", "cdr", typename)
    assert "encoding" in gate.advertise(1, 4, "/torque_request", "protobuf", typename)
    assert "schema" in gate.advertise(1, 5, "/torque_request", "json", "std_msgs/msg/Float64")
    cdr = bytes(clutch_typestore().serialize_cdr(torque_request_msg(5_000_000_123, 42.0),
                                                 typename))
    assert gate.message(1, 1, cdr) is None
    assert gate.message(1, 2, b'{"torque": 7}') is None
    assert "refused" in gate.message(1, 3, cdr)
    assert "not JSON" in gate.message(1, 2, b"{")
    assert "must be a number" in gate.message(1, 2, b'{"torque": "high"}')
    assert got == [(5_000_000_123, "", 42.0), (None, "", 7.0)]
    assert gate.status() == {"client_publish_accepted": 2, "client_publish_refused": 6}
