"""The ROS 2 DDS profile file on the host (payload's ros_dds_profile),
read-only for the containers; its text and path: presets.py."""

from __future__ import annotations

import roles.payload.presets as presets
from robotfleet.host import operations
from robotfleet.host.snapshot import Snapshot, SnapshotQuery


def declare_reads(data, query: SnapshotQuery) -> None:
    if data.ros_preset == "ros2" and data.ros_dds_profile:
        query.files |= {presets.dds_profile_host_path(data), f"/etc/{data.payload_name}"}


def install_files(data, snap: Snapshot) -> None:
    """The ROS 2 DDS profile, read-only for the containers."""
    if data.ros_preset != "ros2" or not data.ros_dds_profile:
        return
    path = presets.dds_profile_host_path(data)
    operations.directory(
        name=f"/etc/{data.payload_name}",
        path=f"/etc/{data.payload_name}",
        current=snap.files.get(f"/etc/{data.payload_name}"),
    )
    operations.file(
        name=f"DDS profile {data.ros_dds_profile}",
        path=path,
        content=presets.dds_profile_text(data),
        current=snap.files.get(path),
        mode="0644",
    )
