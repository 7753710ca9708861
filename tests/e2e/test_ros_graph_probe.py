"""payloadctl's ROS graph check (ros_health) against real ROS: roscore and a
talker from the lab's ROS image (tests/lab/ros_images.py), each started with
plain `docker run` on a network of this test's own; the probe reads the
graph from inside the roscore container as the release gate does.
No lab: it runs with the unit and integration tests (groups.py)."""

from __future__ import annotations

import subprocess
import time
import uuid

import pytest

from roles.payload.payloadctl import health
from tests.lab import ros_images


def docker(*args: str) -> str:
    return subprocess.run(["docker", *args], check=True, capture_output=True, text=True, timeout=300).stdout


@pytest.fixture(scope="module")
def graph():
    """(roscore container, start_talker(rate, topic)) on a network of their own."""
    image = ros_images.build()
    net = f"gh-probe-{uuid.uuid4().hex[:8]}"
    docker("network", "create", net)
    started = []

    def run(name: str, *command: str) -> str:
        full = f"{net}-{name}"
        env = ["-e", f"ROS_HOSTNAME={full}", "-e", f"ROS_MASTER_URI=http://{net}-core:11311"]
        docker("run", "-d", "--rm", "--name", full, "--network", net, *env, image, *command)
        started.append(full)
        return full

    core = run("core", "roscore")
    for _ in range(60):
        if subprocess.run(["docker", "exec", core, "rosnode", "list"], capture_output=True).returncode == 0:
            break
        time.sleep(1)

    def talker(rate: str, topic: str = "/chatter") -> None:
        for name in [n for n in started if n.endswith("-talker")]:
            subprocess.run(["docker", "rm", "-f", name], capture_output=True)
            started.remove(name)
        run("talker", "rostopic", "pub", "-r", rate, topic, "std_msgs/String", "data: hi", "__name:=talker")

    try:
        yield core, talker
    finally:
        for name in started:
            subprocess.run(["docker", "rm", "-f", name], capture_output=True)
        subprocess.run(["docker", "network", "rm", net], capture_output=True)


WANTED = {"nodes": ["/talker"], "topics": {"/chatter": 2.0}, "services": ["/talker/get_loggers"], "wait": 20}


def test_a_talker_at_5_hz_is_healthy_with_2_hz_required(graph):
    core, talker = graph
    talker("5")
    assert health.probe_graph(core, WANTED) == (True, "")


def test_a_misspelled_topic_is_named_with_its_rate(graph):
    core, talker = graph
    talker("5", "/chatterr")
    ok, why = health.probe_graph(core, {**WANTED, "wait": 5})
    assert not ok
    assert why == "/chatter: 0.0 Hz, 2 Hz required (no node publishes it)"


def test_a_talker_too_slow_is_named_with_the_rate_seen(graph):
    core, talker = graph
    talker("1")
    ok, why = health.probe_graph(core, {**WANTED, "wait": 8})
    assert not ok
    assert why.startswith("/chatter: 1.0 Hz, 2 Hz required") or why.startswith("/chatter: 0.9 Hz"), why
