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


def preset(data, address: str, files_dir: Path = FILES_DIR) -> dict:
    """What ros_preset adds: environment (set / dropped), keys every service
    gets unless it sets them, volumes, labels, and extra services."""
    kind = value_of(data, "ros_preset")
    result: dict = {"environment": {}, "drop": [], "keys": {}, "volumes": [], "labels": {}, "extra": {}}
    if kind in ("ros1", "ros2"):
        # roslaunch and ros2 launch shut their nodes down cleanly on SIGINT
        # (Ctrl-C); on Docker's SIGTERM they are killed when the grace ends.
        result["keys"]["stop_signal"] = "SIGINT"
    if kind == "ros1":
        roscore = bool(value_of(data, "ros_roscore"))
        host_network = value_of(data, "payload_network_mode") == "host"
        master = value_of(data, "ros_master_uri") or (
            f"http://{'localhost' if host_network else 'roscore'}:11311" if roscore else None
        )
        if master:
            result["environment"]["ROS_MASTER_URI"] = master
        result["environment"]["ROS_HOSTNAME"] = value_of(data, "ros_hostname") or address
        result["drop"] = ["ROS_DOMAIN_ID"]
        if roscore:
            result["extra"]["roscore"] = {"image": value_of(data, "ros_roscore_image"), "command": ["roscore"]}
            result["keys"]["depends_on"] = ["roscore"]
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
