"""Bags on the robot (issue 52 item 4): ros_bag_dir is a host directory
mounted at /bags in every service of a ROS preset (where `rosbag record -o
/bags/...` writes), which no release or rollback touches, kept under
ros_bag_max_mb by the ROS logs' timer, the oldest files going first.  The
bags recorded across an update and a rollback, on real ROS: tests/e2e/test_ros.py
and tests/e2e/test_ros_health.py."""

from roles.payload import ros_logs
from tests.fixtures import robot_fleet as host_with
from tests.unit.harness import ROBOT, converged, fleet_problems, plan
from tests.unit.rosfleet import NODES, ROS1, rendered

BAGS = {"ros_bag_dir": "/var/lib/ros-bags", "ros_bag_max_mb": 64}
ROS = {**ROBOT, "payload_image": None, "payload_services": NODES, **ROS1, "udev_sensors": []}


def test_every_service_gets_the_bag_directory_at_bags():
    doc = rendered({"payload_services": NODES, **ROS1, **BAGS})
    for service in doc["services"].values():
        assert "/var/lib/ros-bags:/bags" in service["volumes"], service
    assert all(
        "/bags" not in " ".join(s["volumes"])
        for s in rendered({"payload_services": NODES, **ROS1})["services"].values()
    )


def test_the_timer_keeps_the_bags_under_their_size_beside_the_logs():
    text = ros_logs.service_text(type("D", (), {"ros_log_dir": "/var/log/ros", "ros_log_max_mb": 500, **BAGS})())
    assert "payloadctl prune-logs --dir /var/log/ros --max-mb 500\n" in text
    assert "payloadctl prune-logs --dir /var/lib/ros-bags --max-mb 64 --suffix .bag\n" in text


def test_a_robot_gets_the_bag_directory_and_a_converged_one_nothing():
    snap = converged("robots", ROS, "debian-13")  # it ran ROS before, without bags
    sent = "\n".join(str(c) for c in plan({"r1": ("robots", {**ROS, **BAGS}, snap)})["r1"])
    assert "install -d -m 755 -o root -g root /var/lib/ros-bags" in sent
    assert "/etc/systemd/system/robot-payload-ros-logs.service" in sent  # its new ExecStart for the bags
    assert plan({"r1": ("robots", {**ROS, **BAGS}, converged("robots", {**ROS, **BAGS}, "debian-13"))})["r1"] == []


def test_bad_bag_settings_get_one_line():
    assert fleet_problems(host_with(payload_image="r.example.com/a:1", ros_bag_dir="/var/lib/ros-bags")) == [
        "robots.yaml: robot3.ros_bag_dir: needs ros_preset: ros1 or ros2"
    ]
    ros = {"payload_image": "r.example.com/a:1", "ros_preset": "ros1", "ros_master_uri": "http://core:11311"}
    assert fleet_problems(host_with(**ros, ros_bag_dir="/var/log/ros/")) == [
        "robots.yaml: robot3.ros_bag_dir: is ros_log_dir: give the bags a directory of their own"
    ]
    assert fleet_problems(host_with(**ros, ros_bag_dir="/tmp/bags")) == [
        "robots.yaml: robot3.ros_bag_dir: '/tmp/bags' is in the world-writable /tmp; "
        "use a directory only root can write (e.g. under /var/lib)"
    ]
    assert fleet_problems(host_with(**ros, ros_bag_dir="/var/lib/ros-bags", ros_bag_max_mb=5)) == [
        "robots.yaml: robot3.ros_bag_max_mb: expected at least 10, got 5"
    ]


def test_the_guide_s_recorder_is_accepted_and_writes_to_the_bag_directory():
    from tests.lab.ros_graph import guide_vars, with_recorder  # what tests/e2e/test_ros.py deploys on robot2

    graph = with_recorder(guide_vars("reg.example.com/"), "reg.example.com/")
    assert fleet_problems({"robots": {"vars": graph, "hosts": {"robot3": {"address": "10.0.0.3"}}}}) == []
    recorder = rendered(graph)["services"]["recorder"]
    # rosbag's recorder itself as the container's first process: the `rosbag record` wrapper would exit on SIGINT
    # before the bag is closed.
    assert recorder["command"][:3] == ["/usr/lib/rosbag/record", "-o", "/bags/chatter"]
    assert "--split" in recorder["command"]
    assert "/var/lib/ros-bags:/bags" in recorder["volumes"] and recorder["stop_signal"] == "SIGINT"
