"""End to end (issue 52): a real ROS 1 graph (Debian bookworm's roscore and
rostopic, tests/lab/ros_images.py) deployed first time to two robots of the
lab, robot2 on the host's network and robot3 on the project's bridge
network: roscore, a talker and a listener, each its own service, with
`ros_preset: ros1` and `ros_roscore: true` as the docs show them.  Checked
from inside: every node in `rosnode list`, the listener hearing the talker,
ROS_MASTER_URI and ROS_HOSTNAME as roles/payload/README.md says, the graph
back after the payload's unit restarts (what a boot runs), the ROS logs on
the host and kept under ros_log_max_mb; on robot2 the guide's bag
recorder (section 6), its bags kept across an update (every container
recreated) that records new ones, and bounded by ros_bag_max_mb.  At its
end both robots go back to the lab's fleet file (the heartbeat payload) for
the group's later modules; robot2's bags stay."""

from __future__ import annotations

import pytest

from tests.e2e.conftest import BACKGROUND, wait_for

pytestmark = pytest.mark.e2e

HOST_NET, BRIDGE = "robot2", "robot3"
ROBOTS = (HOST_NET, BRIDGE)
PROJECT = "robot-payload"
NODES = ("/rosout", "/talker", "/listener")
BAGS = "/var/lib/ros-bags"


def container(service: str) -> str:
    return f"{PROJECT}-{service}-1"


def limits() -> list[str]:
    return [arg for robot in ROBOTS for arg in ("--limit", robot)]


@pytest.fixture(scope="module")
def graph(lab, first_run, tmp_path_factory):
    from tests.lab import ros_graph, ros_images

    if "ROS image" in BACKGROUND:
        BACKGROUND["ROS image"].wait()
    ros_images.ensure(lab.state)
    # The guide's graph on robot2 and robot3 only (the lab's other hosts keep theirs); robot3 on a bridge,
    # robot2 with the guide's recorder, its logs and bags kept under 10 MB so that the test can pass the bounds.
    fleet = tmp_path_factory.mktemp("ros") / "lab.yaml"
    fleet.write_text(ros_graph.lab_fleet({HOST_NET: recording(), BRIDGE: {"payload_network_mode": "bridge"}}))
    run = lab.provision(*limits(), fleet=fleet, label="(the ROS graph, first release)")
    yield run
    kept = lab.sh(HOST_NET, f"ls {BAGS}")[1].split()  # none if the release failed: the restore runs all the same
    restored = lab.provision(*limits(), label="(robot2, robot3 back to the lab's fleet file)")
    assert restored.returncode == 0, restored.output[-4000:]
    for robot in ROBOTS:
        assert lab.version(robot) == "1.0"
        assert lab.sh(robot, "systemctl is-enabled robot-payload-ros-logs.timer")[1].strip() != "enabled"
    # An update to a release without ROS: the bags stay, the one being written closed by the recorder's stop.
    if kept:
        assert bags(lab) == sorted(name.removesuffix(".active") for name in kept), (kept, bags(lab))


def recording(**more) -> dict:
    """robot2's vars: the guide's graph and recorder, the logs and the bags bounded at 10 MB."""
    from tests.lab import ros_graph

    return {**ros_graph.with_recorder(ros_graph.lab_vars()), "ros_log_max_mb": 10, "ros_bag_max_mb": 10, **more}


def bags(lab, robot: str = HOST_NET) -> list[str]:
    return sorted(lab.ok(robot, f"ls {BAGS}").split())  # the guide's command


def hears(lab, robot: str) -> bool:
    return 'data: "hi"' in lab.ok(robot, f"docker logs {container('listener')} 2>&1")


def nodes(lab, robot: str) -> list[str]:
    return lab.ok(robot, f"docker exec {container('roscore')} rosnode list").split()


def test_the_graph_deploys_first_time_on_both_robots(lab, graph):
    assert graph.returncode == 0, graph.output[-6000:]
    for robot in ROBOTS:
        assert lab.record(robot)["state"] == "active"
        assert all(n in nodes(lab, robot) for n in NODES), (robot, nodes(lab, robot))
        wait_for(lambda: hears(lab, robot), 20, f"{robot}'s listener to hear the talker")
        health = lab.ok(robot, f"docker inspect -f '{{{{.State.Health.Status}}}}' {container('roscore')}")
        assert health.strip() == "healthy"


def test_master_and_hostnames_are_what_the_docs_say(lab, graph):
    def env(robot: str, service: str) -> dict[str, str]:
        lines = lab.ok(robot, f"docker exec {container(service)} env").splitlines()
        return dict(line.split("=", 1) for line in lines if line.startswith("ROS_"))

    for service in ("roscore", "talker", "listener"):
        # Host networking: the master on localhost, each node named by the host's address (the lab's 127.0.0.1).
        assert env(HOST_NET, service)["ROS_MASTER_URI"] == "http://localhost:11311"
        assert env(HOST_NET, service)["ROS_HOSTNAME"] == "127.0.0.1"
        # The project's bridge network: the master and each node by service name.
        assert env(BRIDGE, service)["ROS_MASTER_URI"] == "http://roscore:11311"
        assert env(BRIDGE, service)["ROS_HOSTNAME"] == service
    network = lab.ok(BRIDGE, f"docker inspect -f '{{{{json .NetworkSettings.Networks}}}}' {container('talker')}")
    assert f"{PROJECT}_default" in network


def test_the_graph_is_back_after_the_payload_unit_restarts(lab, graph):
    # What a boot runs: the unit's stop (compose down) and start (the release, nodes after roscore is healthy).
    for robot in ROBOTS:
        lab.ok(robot, "systemctl restart robot-payload")
    for robot in ROBOTS:
        wait_for(lambda: all(n in nodes(lab, robot) for n in NODES), 60, f"{robot}'s graph after the restart")
        wait_for(lambda: hears(lab, robot), 20, f"{robot}'s listener after the restart")
        assert lab.ok(robot, f"docker inspect -f '{{{{.RestartCount}}}}' {container('listener')}").strip() == "0"


def test_ros_logs_land_on_the_host_and_stay_bounded(lab, graph):
    robot = HOST_NET
    listed = lab.ok(robot, "find /var/log/ros -name '*.log' -printf '%f\\n'").split()
    assert {"talker.log", "listener.log", "master.log"} <= set(listed), listed
    assert lab.ok(robot, "systemctl is-enabled robot-payload-ros-logs.timer").strip() == "enabled"
    # An old run's 12 MB log: over ros_log_max_mb (10), the oldest file goes, the nodes' own logs stay.
    lab.ok(robot, "mkdir -p /var/log/ros/old-run && head -c 12M /dev/zero > /var/log/ros/old-run/old.log")
    lab.ok(robot, "touch -d '2026-01-01' /var/log/ros/old-run/old.log && systemctl start robot-payload-ros-logs")
    assert lab.sh(robot, "test -e /var/log/ros/old-run")[0] != 0
    assert lab.ok(robot, "test -s /var/log/ros/talker.log && echo kept").strip() == "kept"


def test_bags_recorded_before_an_update_are_kept_and_its_recorder_records_new_ones(lab, graph, tmp_path):
    from tests.lab import ros_graph

    before = bags(lab)
    assert any(name.endswith(".bag.active") for name in before), before
    # An update: an environment every service gets, so every container is recreated (the recorder's too).
    fleet = tmp_path / "lab.yaml"
    fleet.write_text(ros_graph.lab_fleet({HOST_NET: recording(payload_environment={"RELEASE": "2"})}))
    run = lab.provision("--limit", HOST_NET, fleet=fleet, label="(robot2: an update of the graph)")
    assert run.returncode == 0, run.output[-4000:]
    after = bags(lab)
    # Every bag from before is there, the one being written then closed by the recorder's stop (SIGINT) ...
    closed = sorted(name.removesuffix(".active") for name in before)
    assert set(closed) <= set(after) and all(name.endswith(".bag") for name in closed), (before, after)
    info = lab.ok(HOST_NET, f"docker exec {container('recorder')} rosbag info /bags/{closed[-1]}")
    assert "/chatter" in info and "std_msgs/String" in info and "messages:" in info, info
    # ... and the new release's recorder writes a bag of its own, subscribed to /chatter.
    new = [name for name in after if name not in before and name.endswith(".bag.active")]
    assert len(new) == 1, (before, after)
    subscribers = lab.ok(HOST_NET, f"docker exec {container('roscore')} rostopic info /chatter").split("Subscribers:")[
        1
    ]
    assert "/record_" in subscribers, subscribers
    # An old recording of 12 MB: over ros_bag_max_mb (10), the timer's service removes it, the bags above stay.
    lab.ok(HOST_NET, f"head -c 12M /dev/zero > {BAGS}/old_0.bag && touch -d '2026-01-01' {BAGS}/old_0.bag")
    lab.ok(HOST_NET, "systemctl start robot-payload-ros-logs")
    assert bags(lab) == after, bags(lab)
