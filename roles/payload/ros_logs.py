"""ROS logs on the robot (the ROS presets): every node logs to
``ros_log_dir`` on the host (presets.py mounts it, ROS_LOG_DIR), which no
release or rollback touches, and a timer keeps it under ``ros_log_max_mb``,
the oldest files going first (payloadctl prune-logs).  roslaunch only warns
when its logs pass 1 GB; months of a robot's runs would fill its disk."""

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


def service_text(data) -> str:
    command = shlex.join(
        [installed_files.HELPER, "prune-logs", "--dir", data.ros_log_dir, "--max-mb", str(data.ros_log_max_mb)]
    )
    return f"""# Managed by the robot fleet provisioner (roles/payload).
[Unit]
Description=Keep the ROS logs in {data.ros_log_dir} under {data.ros_log_max_mb} MB (oldest first)

[Service]
Type=oneshot
ExecStart=/usr/bin/python3 {command}
Nice=19
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
        query.files.add(data.ros_log_dir)


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
    operations.directory(
        name=f"ROS logs directory {data.ros_log_dir}", path=data.ros_log_dir, current=snap.files.get(data.ros_log_dir)
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
