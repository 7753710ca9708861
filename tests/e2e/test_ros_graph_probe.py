"""The ROS graph probe (ros_health) against real ROS 1: a roscore and
talkers from the lab's ROS image (Debian bookworm's ros-core,
tests/lab/ros_images.py) on a bridge network of this test's own, labelled
as a compose project's, and payloadctl's gate code (payloadctl/rosgraph.py)
running the probe in the roscore container as it does on a robot.  No lab:
it runs beside the unit tests (groups.WITH_UNIT).  The release rolled back
for its graph, on a simulated robot: tests/e2e/test_ros_health.py."""

from __future__ import annotations

import subprocess
import time
import uuid

import pytest

from roles.payload.payloadctl import rosgraph

pytestmark = pytest.mark.e2e


def docker(*args: str) -> str:
    return subprocess.run(["docker", *args], check=True, capture_output=True, text=True, timeout=300).stdout


@pytest.fixture(scope="module")
def graph():
    """A ROS graph: roscore, a talker at 5 Hz on /chatter, one at 1 Hz on
    /slow and one on a misspelled /scann; yields its project's name."""
    from tests.lab import ros_images

    image = ros_images.build()
    project = f"rosprobe-{uuid.uuid4().hex[:8]}"
    network = project
    docker("network", "create", network)
    started = []

    def run(service: str, *command: str) -> None:
        name = f"{project}-{service}"
        docker(
            "run", "-d", "--name", name, "--network", network, "--network-alias", service,
            "--label", f"com.docker.compose.project={project}", "--label", f"com.docker.compose.service={service}",
            "-e", "ROS_MASTER_URI=http://roscore:11311", "-e", f"ROS_HOSTNAME={service}",
            image, *command,
        )  # fmt: skip
        started.append(name)

    try:
        run("roscore", "roscore")
        deadline = time.monotonic() + 60
        while subprocess.run(
            ["docker", "exec", f"{project}-roscore", "rosnode", "list"], capture_output=True
        ).returncode:
            assert time.monotonic() < deadline, "roscore did not answer within 60 s"
            time.sleep(0.5)
        run("talker", "rostopic", "pub", "-r", "5", "/chatter", "std_msgs/String", "data: hi", "__name:=talker")
        run("slow", "rostopic", "pub", "-r", "1", "/slow", "std_msgs/String", "data: hi", "__name:=slow")
        run("typo", "rostopic", "pub", "-r", "5", "/scann", "std_msgs/String", "data: hi", "__name:=typo")
        yield project
    finally:
        for name in started:
            subprocess.run(["docker", "rm", "-f", name], capture_output=True)
        subprocess.run(["docker", "network", "rm", network], capture_output=True)


def test_a_graph_that_publishes_what_it_must_passes(graph):
    wanted = {"nodes": ["/talker"], "topics": {"/chatter": 2.0}, "services": ["/rosout/get_loggers"]}
    report = rosgraph.probe(graph, wanted, 30)  # tries again while the talker starts
    assert report["ok"], report
    assert 4.0 <= report["rates"]["/chatter"] <= 6.0, report
    assert {"/talker", "/rosout"} <= set(report["nodes"])


def test_a_misspelled_topic_a_slow_one_and_a_missing_node_each_give_their_line(graph):
    rosgraph.probe(graph, {"nodes": ["/slow", "/typo"]}, 30)  # both talkers registered first
    wanted = {"nodes": ["/talker", "/listener"], "topics": {"/chatter": 2.0, "/scan": 2.0, "/slow": 2.0}}
    report = rosgraph.probe(graph, wanted, 0)
    assert not report["ok"]
    assert report["problems"] == [
        "/listener: node not up",
        "/scan: 0.0 Hz, 2 Hz required (no node publishes it; did you mean /scann?)",
        "/slow: 1.0 Hz, 2 Hz required",
    ], report
    assert 4.0 <= report["rates"]["/chatter"] <= 6.0


def test_the_gate_names_the_graph_in_its_reason(graph):
    class Spec:
        name = graph
        compose = {rosgraph.KEY: {"topics": {"/slow": 2.0}}}

    started = time.monotonic()
    ok, why = rosgraph.gate(Spec, 0)  # the gate gives the graph at least MIN_WITHIN seconds
    assert (ok, why) == (False, "ROS graph: /slow: 1.0 Hz, 2 Hz required")
    assert rosgraph.MIN_WITHIN - 3 <= time.monotonic() - started < rosgraph.MIN_WITHIN + 10  # tried again meanwhile


def test_a_project_without_a_running_roscore_is_one_line():
    report = rosgraph.probe(f"absent-{uuid.uuid4().hex[:8]}", {"topics": {"/chatter": 2.0}}, 0)
    assert report == {
        "ok": False,
        "problems": ["no running roscore container to read the graph from"],
        "rates": {},
        "nodes": [],
    }


def test_status_looks_at_the_current_release_s_graph_once(graph):
    class Releases:
        def __init__(self, health, autostart=True):
            self.health, self.autostart = health, autostart

        def spec(self, rid):
            return type(
                "Spec", (), {"compose": {rosgraph.KEY: self.health} if self.health else {}, "autostart": self.autostart}
            )

    assert rosgraph.now_verdict(Releases({"topics": {"/chatter": 2.0}}), graph, "r1") == "ok"
    assert rosgraph.now_verdict(Releases({"topics": {"/slow": 2.0}}), graph, "r1") == "/slow: 1.0 Hz, 2 Hz required"
    assert rosgraph.now_verdict(Releases(None), graph, "r1") is None  # declares no graph
    assert rosgraph.now_verdict(Releases({"topics": {"/slow": 2.0}}, autostart=False), graph, "r1") is None  # staged
    assert rosgraph.now_verdict(Releases({"topics": {"/slow": 2.0}}), graph, None) is None  # never deployed
