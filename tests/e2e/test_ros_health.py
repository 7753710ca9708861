"""End to end (issue 52 item 3): a release judged by its ROS graph.  The
guide's graph (tests/lab/ros_graph.py) with `ros_health` asking /chatter
at 2 Hz, on robot2 (the host's network), but its talker publishes once and
then stays up, silent (`rostopic pub` without -r: one latched message).
Every container runs, roscore is healthy: only the graph says the release
is broken, and the gate rolls it back to what ran before, naming the topic
and the rate it saw.  The probe on real ROS in detail (healthy, a
misspelled topic, a slow one; the bridge network):
tests/e2e/test_ros_graph_probe.py; the guide's graph passing the gate on
the host's network and on a bridge: tests/e2e/test_ros.py's first release
(the guide's block asks for it).  The release records bags too (the
guide's recorder, docs/guides/ros-payload.md section 6): the rollback keeps
the one it wrote, closed by its stop, and every bag from before it.  Two deploys of one robot: the silent
release, then the lab's fleet file again (the ROS preset's log timer goes)."""

from __future__ import annotations

import pytest

from tests.e2e.conftest import BACKGROUND

pytestmark = pytest.mark.e2e

ROBOT = "robot2"
SILENT = ["rostopic", "pub", "/chatter", "std_msgs/String", "data: hi", "__name:=talker"]
BAGS = "/var/lib/ros-bags"
HEALTH = {"nodes": ["/talker", "/listener"], "topics": {"/chatter": "2 Hz"}}


def test_a_release_whose_topic_is_silent_is_rolled_back_with_the_rate_it_saw(lab, first_run, tmp_path):
    from tests.lab import ros_graph, ros_images

    if "ROS image" in BACKGROUND:
        BACKGROUND["ROS image"].wait()
    ros_images.ensure(lab.state)
    before = lab.record(ROBOT)["id"]
    graph = ros_graph.with_recorder(ros_graph.lab_vars())
    graph["payload_services"]["talker"]["command"] = SILENT
    # The graph check looks again until payload_health_timeout runs out: short, for a silent topic.
    more = {**graph, "ros_health": HEALTH, "payload_health_timeout": 20}
    bags_before = set(lab.sh(ROBOT, f"ls {BAGS}")[1].split())  # test_ros.py's, when it ran before
    fleet = tmp_path / "lab.yaml"
    fleet.write_text(ros_graph.lab_fleet({ROBOT: more}))
    run = lab.provision("--limit", ROBOT, fleet=fleet, label="(robot2: the graph, its topic silent)")
    try:
        assert run.returncode != 0, run.output[-4000:]
        line = next(x for x in run.output.splitlines() if f"[{ROBOT}]" in x and "payload: release" in x)
        assert "(ROS graph is not healthy (ros_health): /chatter: 0.0 Hz, 2 Hz required)" in line, line
        assert f"rolled back to {before} and it is running" in line, line
        assert lab.record(ROBOT)["id"] == before
        failed = lab.record(ROBOT, "releases/" + line.split("payload: release ")[1].split()[0])
        assert (
            failed["state"] == "failed"
            and failed["reason"] == "ROS graph is not healthy (ros_health): /chatter: 0.0 Hz, 2 Hz required"
        )
        assert lab.version(ROBOT) == "1.0"  # the lab's heartbeat payload runs again
        # The bags from before are kept, and so is the one the rolled-back release recorded, closed by its stop.
        bags_after = set(lab.ok(ROBOT, f"ls {BAGS}").split())
        assert bags_before <= bags_after, (bags_before, bags_after)
        recorded = bags_after - bags_before
        assert len(recorded) == 1 and next(iter(recorded)).endswith(".bag"), recorded
    finally:
        restored = lab.provision("--limit", ROBOT, label="(robot2 back to the lab's fleet file)")
        assert restored.returncode == 0, restored.output[-4000:]
