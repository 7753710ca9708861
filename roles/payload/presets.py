"""What ``ros_preset`` adds to the payload's services: the ROS 1 / ROS 2
environment, ``ipc``, the stop signal, a DDS profile from files/dds/, a
roscore service."""

from __future__ import annotations

import hashlib
import xml.etree.ElementTree as ElementTree
from pathlib import Path

from robotfleet import CHECKOUT
from roles.payload.services import value_of

FILES_DIR = CHECKOUT / "files"
DDS_DIR = "dds"
CONTAINER_DDS_DIR = "/etc/ros/dds"
PROFILE_LABEL = "io.robot-fleet.dds-profile"
CONTAINER_LOG_DIR = "/var/log/ros"
CONTAINER_BAG_DIR = "/bags"


def dds_vendor(xml_text: str) -> str | None:
    """'cyclonedds' or 'fastdds' by the profile's root element, else None."""
    try:
        root = ElementTree.fromstring(xml_text)
    except ElementTree.ParseError:
        return None
    tag = root.tag.rsplit("}", 1)[-1]
    if tag == "CycloneDDS":
        return "cyclonedds"
    if tag in ("profiles", "dds"):
        return "fastdds"
    return None


def dds_profile_host_path(data) -> str:
    return f"/etc/{value_of(data, 'payload_name')}/{value_of(data, 'ros_dds_profile')}"


def dds_profile_text(data, files_dir: Path = FILES_DIR) -> str | None:
    name = value_of(data, "ros_dds_profile")
    if not name:
        return None
    try:
        return (files_dir / DDS_DIR / name).read_text()
    except OSError:
        return None


ROSCORE = "roscore"
ROSCORE_PORT = 11311
# Healthy once the master answers getSystemState (ROS Master API); any error, refused connection included, exits 1.
ROSCORE_PROBE = (
    "import sys, xmlrpc.client as x; "
    f"sys.exit(0 if x.ServerProxy('http://localhost:{ROSCORE_PORT}').getSystemState('/health')[0] == 1 else 1)"
)
# Probed every second while it starts (Docker 25+; payloadctl drops start_interval on older engines), then every 10 s.
ROSCORE_HEALTHCHECK = {
    "test": ["CMD", "python3", "-c", ROSCORE_PROBE],
    "interval": "10s",
    "timeout": "5s",
    "retries": 3,
    "start_period": "60s",
    "start_interval": "1s",
}
# Every node starts once the master answers, and compose restarts it when it restarts roscore.
WAIT_FOR_ROSCORE = {ROSCORE: {"condition": "service_healthy", "restart": True}}


def for_service(extra: dict, name: str) -> dict:
    """The preset as service ``name`` gets it: on the project's network
    (bridge) each ROS 1 node is reached by its service name."""
    if not extra.get("hostname_is_service"):
        return extra
    return {**extra, "environment": {**extra["environment"], "ROS_HOSTNAME": name}}


def preset(data, address: str, files_dir: Path = FILES_DIR) -> dict:
    """What ros_preset adds: environment (set / dropped), keys every service
    gets unless it sets them, volumes, labels, and extra services."""
    kind = value_of(data, "ros_preset")
    result: dict = {"environment": {}, "drop": [], "keys": {}, "volumes": [], "labels": {}, "extra": {}}
    if kind in ("ros1", "ros2"):
        # roslaunch and ros2 launch shut their nodes down cleanly on SIGINT (Ctrl-C), what
        # they are written for; a process that handles only SIGINT is killed at the grace's end
        # on Docker's SIGTERM (roslaunch 1.16 handles both: tests/bench/roslaunch_stop.py).
        result["keys"]["stop_signal"] = "SIGINT"
        # Logs outlive the containers, on the host, kept under ros_log_max_mb (ros_logs.py).
        result["environment"]["ROS_LOG_DIR"] = CONTAINER_LOG_DIR
        result["volumes"].append(f"{value_of(data, 'ros_log_dir')}:{CONTAINER_LOG_DIR}")
        # Bags (rosbag record -o /bags/...) outlive the containers the same way, kept under ros_bag_max_mb.
        if value_of(data, "ros_bag_dir"):
            result["volumes"].append(f"{value_of(data, 'ros_bag_dir')}:{CONTAINER_BAG_DIR}")
    if kind == "ros1":
        roscore = bool(value_of(data, "ros_roscore"))
        host_network = value_of(data, "payload_network_mode") == "host"
        # Docker's default bridge network resolves no names: the graph runs on the project's own network.
        project_network = roscore and value_of(data, "payload_network_mode") == "bridge"
        master = value_of(data, "ros_master_uri") or (
            f"http://{'localhost' if host_network else ROSCORE}:{ROSCORE_PORT}" if roscore else None
        )
        if master:
            result["environment"]["ROS_MASTER_URI"] = master
        result["environment"]["ROS_HOSTNAME"] = value_of(data, "ros_hostname") or address
        result["hostname_is_service"] = project_network and not value_of(data, "ros_hostname")
        result["drop"] = ["ROS_DOMAIN_ID"]
        if project_network:
            result["unset"] = ["network_mode"]
        if roscore:
            result["extra"][ROSCORE] = {
                "image": value_of(data, "ros_roscore_image"),
                "command": ["roscore"],
                "healthcheck": ROSCORE_HEALTHCHECK,
            }
            result["keys"]["depends_on"] = WAIT_FOR_ROSCORE
    elif kind == "ros2":
        result["environment"]["ROS_DOMAIN_ID"] = str(value_of(data, "ros_domain_id", 0))
        result["drop"] = ["ROS_MASTER_URI", "ROS_HOSTNAME"]
        # Shared-memory transports (Fast DDS SHM, iceoryx) need one IPC namespace.
        result["keys"]["ipc"] = "host"
        text = dds_profile_text(data, files_dir)
        if text is not None:
            name = value_of(data, "ros_dds_profile")
            inside = f"{CONTAINER_DDS_DIR}/{name}"
            if dds_vendor(text) == "cyclonedds":
                result["environment"]["CYCLONEDDS_URI"] = f"file://{inside}"
                result["environment"]["RMW_IMPLEMENTATION"] = "rmw_cyclonedds_cpp"
            else:
                result["environment"]["FASTRTPS_DEFAULT_PROFILES_FILE"] = inside
                result["environment"]["FASTDDS_DEFAULT_PROFILES_FILE"] = inside
                result["environment"]["RMW_IMPLEMENTATION"] = "rmw_fastrtps_cpp"
            result["volumes"].append(f"{dds_profile_host_path(data)}:{inside}:ro")
            # A changed profile is a new release: the containers must reread it.
            result["labels"][PROFILE_LABEL] = hashlib.sha256(text.encode()).hexdigest()[:16]
    return result
