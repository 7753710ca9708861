"""A ROS 1 fleet's payload as the unit tests render it: two nodes, the ros1
preset's settings, and the compose file the payload role would write."""

from __future__ import annotations

import yaml

from roles.payload import compose
from tests.unit.harness import desired_compose, merged

REG = "reg.example.com"
NODES = {
    "talker": {"image": f"{REG}/ros/noetic-ros-core:1.16", "command": ["rostopic", "pub", "/chatter", "x"]},
    "listener": {"image": f"{REG}/ros/noetic-ros-core:1.16", "command": ["rostopic", "echo", "/chatter"]},
}
ROS1 = {"ros_preset": "ros1", "ros_roscore": True, "ros_roscore_image": f"{REG}/ros/noetic-ros-core:1.16"}


def rendered(extra: dict, address="10.0.0.9") -> dict:
    data = merged("robots", {"payload_image": None, **extra})
    return yaml.safe_load(compose.dump(desired_compose(data, address)))
