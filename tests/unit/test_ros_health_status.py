"""robotfleet status and ros_health: payloadctl status asks the current
release's graph check (its spec's ``checks``) for one look, and the row
shows the verdict (GRAPH, --json's ``graph``), counts a graph that falls
short as drift and gives it a gauge.  The look itself runs against real
ROS in tests/e2e/test_ros_graph_probe.py (health.probe_graph)."""

import json

from robotfleet.commands import status
from roles.payload import report
from roles.payload.payloadctl import health
from roles.payload.payloadctl import status as payloadctl_status

IMAGE = "reg.example.com/ros/noetic-ros-core:1.16"
GRAPH = {"service": "roscore", "nodes": ["/talker"], "topics": {"/chatter": 2.0}, "services": [], "wait": 120}


class Releases:
    def __init__(self, checks, autostart=True):
        self.checks, self.autostart = checks, autostart

    def spec(self, rid):
        return type("Spec", (), {"checks": self.checks, "autostart": self.autostart})


def test_payloadctl_status_takes_one_look_with_the_current_release_s_graph_check(monkeypatch):
    asked = []

    def graph_healthy(name, wanted):
        asked.append((name, wanted))
        return False, "/chatter: 0.0 Hz, 2 Hz required"

    monkeypatch.setattr(health, "graph_healthy", graph_healthy)
    checks = [{"command": ["nvidia-smi", "-L"], "failure": "cannot see a GPU"}, {"graph": GRAPH, "failure": "x"}]
    verdict = payloadctl_status.graph_verdict(Releases(checks), "robot-payload", "r1")
    assert verdict == "/chatter: 0.0 Hz, 2 Hz required"
    assert asked == [("robot-payload", {**GRAPH, "wait": 0})]  # one look, not the gate's wait
    monkeypatch.setattr(health, "graph_healthy", lambda name, wanted: (True, ""))
    assert payloadctl_status.graph_verdict(Releases(checks), "robot-payload", "r1") == "ok"
    assert payloadctl_status.graph_verdict(Releases(checks[:1]), "robot-payload", "r1") is None  # no ros_health
    assert payloadctl_status.graph_verdict(Releases(checks, autostart=False), "robot-payload", "r1") is None  # staged
    assert payloadctl_status.graph_verdict(Releases(checks), "robot-payload", None) is None  # never deployed


def row(graph):
    found = {
        "current": {"id": "r2", "state": "active", "images": {IMAGE: {"pinned": IMAGE + "@sha256:" + "a" * 64}}},
        "containers": [{"status": "running", "health": "healthy", "restarts": 0}],
        "graph": graph,
    }
    return {"host": "robot2", "reachable": True, **report.cells(json.dumps(found))}


def test_status_shows_the_graph_s_verdict_and_a_graph_that_falls_short_is_drift():
    slow = row("/chatter: 0.0 Hz, 2 Hz required")
    assert slow["graph"] == "/chatter: 0.0 Hz, 2 Hz required"
    assert report.missing(slow, [IMAGE]) == "ROS graph: /chatter: 0.0 Hz, 2 Hz required"
    assert report.missing(row("ok"), [IMAGE]) is None and report.missing(row(None), [IMAGE]) is None
    assert ("graph", "GRAPH") in report.STATUS.columns and "graph" in report.STATUS.wide
    table = status.table([slow], list(report.STATUS.columns)).splitlines()
    assert "GRAPH" in table[0] and "/chatter: 0.0 Hz, 2 Hz required" in table[1]
    assert {m.name: m.value for m in report.metrics(slow)}["payload_ros_graph_ok"] == 0
    assert {m.name: m.value for m in report.metrics(row("ok"))}["payload_ros_graph_ok"] == 1
    assert "payload_ros_graph_ok" not in {m.name for m in report.metrics(row(None))}
