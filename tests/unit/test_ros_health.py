"""ros_health in the fleet file: graph names, rates above 0, ROS 1 with
roscore; one line naming host and field.  Its probe on real ROS:
tests/e2e/test_ros_graph_probe.py."""

from roles.payload import ros_health
from tests.unit.harness import fleet_problems

REG = "reg.example.com"
ROS1 = {
    "payload_image": None,
    "ros_preset": "ros1",
    "ros_roscore": True,
    "ros_roscore_image": f"{REG}/ros/noetic-ros-core:1.16",
    "payload_services": {"talker": {"image": f"{REG}/ros/noetic-ros-core:1.16", "command": ["rostopic"]}},
}


def problems(health, **more):
    return fleet_problems(
        {"robots": {"hosts": {"robot3": {"address": "10.0.0.3", **ROS1, **more, "ros_health": health}}}}
    )


def test_a_graph_of_nodes_topics_and_services_is_accepted_and_becomes_the_release_check():
    health = {
        "nodes": ["/talker"],
        "topics": {"/chatter": "2 Hz", "/scan/front": 10},
        "services": ["/rosout/get_loggers"],
    }
    assert problems(health) == []
    check = ros_health.graph_check({**ROS1, "ros_health": health, "payload_health_timeout": 30})
    assert check["graph"]["topics"] == {"/chatter": 2.0, "/scan/front": 10.0} and check["graph"]["wait"] == 30
    assert check["graph"]["service"] == "roscore" and check["graph"]["nodes"] == ["/talker"]


def test_a_bad_name_a_rate_of_zero_or_no_rate_and_an_unknown_key_each_get_one_line():
    lines = problems({"nodes": ["talker"], "topics": {"/chatter": "0 Hz", "/scan": "fast"}, "node": []})
    assert len(lines) == 4, lines
    assert all("robot3" in line and "ros_health" in line for line in lines)
    text = "\n".join(lines)
    assert "ros_health.nodes[0]" in text and "a global ROS graph name" in text
    assert "ros_health.topics.'/chatter'" in text and "above 0 Hz" in text
    assert "ros_health.topics.'/scan'" in text and "a rate such as 2 Hz" in text
    assert "ros_health.node" in text and "unknown key" in text


def test_it_needs_ros1_with_the_project_s_roscore():
    (line,) = problems({"topics": {"/chatter": 2}}, ros_roscore=False, ros_master_uri="http://10.0.0.1:11311")
    assert "robot3" in line and "ros_health" in line and "ros_roscore: true" in line
