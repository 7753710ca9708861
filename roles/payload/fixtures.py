"""Test fixtures: what a successful release leaves on a host."""

import json

import roles.payload.compose as compose
import roles.payload.hooks as hooks
import roles.payload.installed_files as installed_files
import roles.payload.ros_logs as ros_logs
import roles.payload.secret_files as secret_files
import roles.payload.services as services
import roles.payload.steps as steps
from robotfleet.host.fixtures import file_state
from robotfleet.host.snapshot import FileState


def desired(play, host: str) -> dict:
    """The compose document the deploy computes for ``play``'s host."""
    data = play.data
    additions = play.added(hooks.SERVICES, services.declared(data))
    return compose.project(data, data.get("ssh_hostname") or host, additions)


def converged(play, host: str) -> None:
    data, snap = play.data, play.snapshot
    additions = play.added(hooks.SERVICES, services.declared(data))
    snap.files.update(
        {
            data.payload_dir: FileState("dir", None, "755", "root", "root"),
            installed_files.HELPER: file_state(installed_files.helper_bytes(), "755"),
        }
    )
    if secret_files.names(data):
        snap.files[secret_files.directory(data.payload_dir)] = FileState("dir", None, "700", "root", "root")
        for name, content in secret_files.read(data).items():
            snap.files[secret_files.robot_path(data, name)] = file_state(content, "600")
    if ros_logs.enabled(data):
        for directory, _, _ in ros_logs.bounded(data):
            snap.files[directory] = FileState("dir", None, "755", "root", "root")
        service, timer = ros_logs.unit_paths(data)
        snap.files[service] = file_state(ros_logs.service_text(data))
        snap.files[timer] = file_state(ros_logs.timer_text(data))
        snap.units[f"{ros_logs.unit_name(data)}.timer"] = ("enabled", "active")
    if data.payload_autostart:
        snap.files[installed_files.unit_path(data)] = file_state(
            installed_files.unit_text(data, steps.unit_devices(additions))
        )
        snap.units[f"{data.payload_name}.service"] = ("enabled", "active")
        snap.probes["payload_containers"] = "c\trunning\tUp 3 hours (healthy)\n"
    doc = compose.project(data, data.get("ssh_hostname") or host, additions)
    state = "active" if data.payload_autostart else "staged"
    snap.probes["payload_record"] = json.dumps(
        {"spec_hash": compose.spec_hash(doc, data.payload_autostart), "state": state}
    )
