"""ros_health: checked in the fleet file (one line per bad entry, naming
host and field, all at once), carried by the release's compose document,
and the probe's own arithmetic (TCPROS headers, a rate from arrival times).
The probe against real ROS: tests/integration/test_ros_graph_probe.py."""

import struct

import yaml

from roles.payload import compose
from roles.payload.payloadctl import rosgraph, rosgraph_probe
from tests.unit.harness import desired_compose, fleet_problems, merged

REG = "reg.example.com"
IMAGE = f"{REG}/ros/noetic-ros-core:1.16"
ROS1 = {"ros_preset": "ros1", "ros_roscore": True, "ros_roscore_image": IMAGE, "payload_image": None}
NODES = {"talker": {"image": IMAGE, "command": ["rostopic", "pub", "-r", "5", "/chatter", "std_msgs/String", "hi"]}}


def fleet(robot2: dict, vars_: dict = ROS1) -> dict:
    return {
        "robots": {
            "vars": {**vars_, "payload_services": NODES},
            "hosts": {"robot1": {"address": "10.0.0.1"}, "robot2": {"address": "10.0.0.2", **robot2}},
        }
    }


def test_a_good_ros_health_is_accepted_and_travels_in_the_release_as_global_names_and_hz():
    health = {"nodes": ["/talker", "listener"], "topics": {"/chatter": "2 Hz", "scan": 10}, "services": ["/srv"]}
    assert fleet_problems(fleet({"ros_health": health})) == []
    data = merged("robots", {**ROS1, "payload_services": NODES, "ros_health": health})
    doc = yaml.safe_load(compose.dump(desired_compose(data, "10.0.0.2")))
    assert doc[rosgraph.KEY] == {
        "nodes": ["/talker", "/listener"],
        "topics": {"/chatter": 2.0, "/scan": 10.0},
        "services": ["/srv"],
    }
    assert rosgraph.expected(doc) == doc[rosgraph.KEY]


def test_without_ros_health_the_release_carries_nothing_and_its_identity_is_unchanged():
    data = merged("robots", {**ROS1, "payload_services": NODES})
    doc = desired_compose(data, "10.0.0.2")
    assert rosgraph.KEY not in doc and rosgraph.expected(doc) is None
    with_health = desired_compose(merged("robots", {**data, "ros_health": {"topics": {"/chatter": 2}}}), "10.0.0.2")
    # A changed ros_health is a new release (what identifies it includes the graph it must show).
    assert compose.spec_hash(with_health, True) != compose.spec_hash(doc, True)


def test_every_bad_entry_is_one_line_naming_host_and_field_all_at_once():
    bad = {
        "nodes": ["/talker", "~private", "/talker"],
        "topics": {"/chatter": 0, "/scan": "fast", "bad name": 2, "/odom": -1},
        "servces": ["/srv"],
    }
    lines = fleet_problems(fleet({"ros_health": bad}))
    assert len(lines) == 7, lines
    assert all(line.startswith("robots.yaml: robot2.ros_health.") for line in lines)
    text = "\n".join(lines)
    assert "robot2.ros_health.nodes[1]: expected a ROS graph name like /chatter" in text
    assert "robot2.ros_health.nodes[2]: duplicate entry" in text
    assert "robot2.ros_health.topics.'/chatter': expected a rate above 0 Hz" in text
    assert "robot2.ros_health.topics.'/odom': expected a rate above 0 Hz" in text
    assert "robot2.ros_health.topics.'/scan': expected a rate like 2 Hz, got 'fast'" in text
    assert "robot2.ros_health.topics.'bad name': expected a ROS graph name" in text
    assert "robot2.ros_health.servces: not a key of ros_health (did you mean 'services'?)" in text
    assert not any("robot1." in line for line in lines)


def test_ros_health_without_the_project_s_roscore_is_refused():
    without = {"ros_preset": "ros1", "ros_master_uri": "http://10.0.0.5:11311", "payload_image": None}
    lines = fleet_problems(fleet({"ros_health": {"topics": {"/chatter": 2}}}, without))
    assert lines == [
        "robots.yaml: robot2.ros_health: needs ros_preset: ros1 and ros_roscore: true "
        "(the graph is read from inside the project's roscore)"
    ]


def test_a_rate_reads_as_hz_from_a_number_or_text():
    from roles.payload.ros_health import rate

    assert [rate(2), rate(2.5), rate("2 Hz"), rate("0.5Hz"), rate(" 10 ")] == [2.0, 2.5, 2.0, 0.5, 10.0]
    assert [rate(True), rate("2 kHz"), rate(None), rate("Hz")] == [None] * 4


def test_tcpros_headers_round_trip_and_frames_are_length_prefixed():
    fields = {"callerid": "/probe", "topic": "/chatter", "md5sum": "*", "type": "*"}
    encoded = rosgraph_probe.encode_header(fields)
    (size,) = struct.unpack("<I", encoded[:4])
    assert size == len(encoded) - 4
    assert rosgraph_probe.decode_header(encoded[4:]) == fields
    # a value may hold "=" (only the first one splits)
    assert rosgraph_probe.decode_header(rosgraph_probe.encode_header({"error": "a=b"})[4:]) == {"error": "a=b"}


def test_a_rate_comes_from_the_intervals_and_the_window_fits_the_required_rate():
    assert rosgraph_probe.rate_of([0.0, 0.2, 0.4, 0.6, 0.8], 2.0) == 5.0
    assert rosgraph_probe.rate_of([], 2.0) == 0.0
    assert rosgraph_probe.rate_of([1.5], 2.0) == 0.5  # one message in the window: no interval to measure
    assert rosgraph_probe.window(2.0) == 2.5 and rosgraph_probe.window(0.5) == 6.0
    assert rosgraph_probe.window(0.001) == rosgraph_probe.MAX_WINDOW


def test_the_gate_passes_a_release_that_declares_no_graph_without_looking():
    class Spec:
        name, compose = "robot-payload", {"services": {}}

    assert rosgraph.gate(Spec, 30) == (True, "")


def test_the_probe_s_source_is_read_from_payloadctl_itself():
    assert "def probe(expected)" in rosgraph.probe_source()


def test_status_shows_the_graph_s_verdict_and_a_graph_that_falls_short_is_drift():
    import json

    from robotfleet.commands import status
    from roles.payload import report

    def row(graph):
        found = {
            "current": {"id": "r2", "state": "active", "images": {IMAGE: {"pinned": IMAGE + "@sha256:" + "a" * 64}}},
            "containers": [{"status": "running", "health": "healthy", "restarts": 0}],
            "graph": graph,
        }
        return {"host": "robot2", "reachable": True, **report.cells(json.dumps(found))}

    slow = row("/chatter: 0.0 Hz, 2 Hz required")
    assert slow["graph"] == "/chatter: 0.0 Hz, 2 Hz required"
    assert report.missing(slow, [IMAGE]) == "ROS graph: /chatter: 0.0 Hz, 2 Hz required"
    assert report.missing(row("ok"), [IMAGE]) is None and report.missing(row(None), [IMAGE]) is None
    assert ("graph", "GRAPH") in report.STATUS.columns
    table = status.table([slow], list(report.STATUS.columns)).splitlines()
    assert "GRAPH" in table[0] and "/chatter: 0.0 Hz, 2 Hz required" in table[1]
    gauges = {m.name: m.value for m in report.metrics(slow)}
    assert gauges["payload_ros_graph_ok"] == 0
    assert {m.name: m.value for m in report.metrics(row("ok"))}["payload_ros_graph_ok"] == 1
    assert "payload_ros_graph_ok" not in {m.name for m in report.metrics(row(None))}
