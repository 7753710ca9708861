"""ROS logs on the robot (the ROS presets): every node logs to
``ros_log_dir`` on the host (presets.py mounts it, ROS_LOG_DIR), which no
release or rollback touches, and a timer keeps it under ``ros_log_max_mb``,
the oldest files going first (payloadctl prune-logs).  roslaunch only warns
when its logs pass 1 GB; months of a robot's runs would fill its disk.
``ros_bag_dir`` (mounted at /bags, for ``rosbag record``) is kept the same
way under ``ros_bag_max_mb`` by the same timer."""

from __future__ import annotations

import shlex

from pyinfra.operations.util import any_changed

import roles.payload.installed_files as installed_files
from robotfleet.host import operations
from robotfleet.host.snapshot import Snapshot, SnapshotQuery

EVERY = "10min"


def enabled(data) -> bool:
    return data.ros_preset in ("ros1", "ros2")


def unit_name(data) -> str:
    return f"{data.payload_name}-ros-logs"


def unit_paths(data) -> tuple[str, str]:
    return tuple(f"/etc/systemd/system/{unit_name(data)}.{kind}" for kind in ("service", "timer"))


def bounded(data) -> list[tuple[str, int, list[str]]]:
    """(directory, MB, more arguments) the timer keeps: the logs, and the
    bags where ros_bag_dir is set (only *.bag files: the directory is the user's)."""
    found = [(data.ros_log_dir, data.ros_log_max_mb, [])]
    return found + [(data.ros_bag_dir, data.ros_bag_max_mb, ["--suffix", ".bag"])] if data.ros_bag_dir else found


def service_text(data) -> str:
    starts = "".join(
        "ExecStart=/usr/bin/python3 "
        + shlex.join([installed_files.HELPER, "prune-logs", "--dir", directory, "--max-mb", str(mb), *more])
        + "\n"
        for directory, mb, more in bounded(data)
    )
    bags = f" and the bags in {data.ros_bag_dir} under {data.ros_bag_max_mb} MB" if data.ros_bag_dir else ""
    return f"""# Managed by the robot fleet provisioner (roles/payload).
[Unit]
Description=Keep the ROS logs in {data.ros_log_dir} under {data.ros_log_max_mb} MB{bags} (oldest first)

[Service]
Type=oneshot
{starts}Nice=19
IOSchedulingClass=idle
"""


def timer_text(data) -> str:
    return f"""# Managed by the robot fleet provisioner (roles/payload).
[Unit]
Description=Keep the ROS logs in {data.ros_log_dir} under {data.ros_log_max_mb} MB, every {EVERY}

[Timer]
OnBootSec=2min
OnUnitActiveSec={EVERY}

[Install]
WantedBy=timers.target
"""


def declare_reads(data, query: SnapshotQuery) -> None:
    query.files |= set(unit_paths(data))
    query.units.add(f"{unit_name(data)}.timer")
    if enabled(data):
        query.files |= {directory for directory, _, _ in bounded(data)}


def install(data, snap: Snapshot) -> None:
    """The log directory and the timer that bounds it; without a preset, the timer removed."""
    service_path, timer_path = unit_paths(data)
    timer = f"{unit_name(data)}.timer"
    if not enabled(data):
        removed = operations.absent(name="Remove the ROS logs timer", paths=list(unit_paths(data)), present=snap.files)
        operations.run(
            name="Stop the ROS logs timer",
            script=f"systemctl disable --now {shlex.quote(timer)} 2>/dev/null; systemctl daemon-reload",
            _if=removed.did_change,
        )
        return
    for (directory, _, _), what in zip(bounded(data), ("logs", "bags")):
        operations.directory(
            name=f"ROS {what} directory {directory}", path=directory, current=snap.files.get(directory)
        )
    written = [
        operations.file(name=f"Write {path.rsplit('/', 1)[1]}", path=path, content=text, current=snap.files.get(path))
        for path, text in ((service_path, service_text(data)), (timer_path, timer_text(data)))
    ]
    operations.run(
        name="systemd daemon-reload (ROS logs timer)",
        script=f"systemctl daemon-reload && systemctl restart {shlex.quote(timer)}",
        _if=any_changed(*written),
    )
    operations.service(
        name=f"Enable and start {timer}",
        unit=timer,
        enabled_now=snap.unit_enabled(timer),
        active_now=snap.unit_active(timer),
    )
