"""Run deploy.py through pyinfra against @fake hosts whose snapshot output is
canned, and return the commands each host would be sent."""

from __future__ import annotations

import base64
import re
from pathlib import Path

from pyinfra.api import Config, Inventory, State
from pyinfra.api.exceptions import PyinfraError
from pyinfra.api.connect import connect_all, disconnect_all
from pyinfra.api.operations import run_ops
from pyinfra.context import ctx_state

from roles.fleet import read_group_data
from roles.hoststate import FileState, Snapshot

ROOT = Path(__file__).resolve().parents[2]
SNAPSHOT_MARK = "export LC_ALL=C"

OS_RELEASES = {
    "ubuntu-20.04": {"id": "ubuntu", "id_like": "debian", "version_id": "20.04", "version_codename": "focal", "ubuntu_codename": "focal"},
    "ubuntu-22.04": {"id": "ubuntu", "id_like": "debian", "version_id": "22.04", "version_codename": "jammy", "ubuntu_codename": "jammy"},
    "ubuntu-24.04": {"id": "ubuntu", "id_like": "debian", "version_id": "24.04", "version_codename": "noble", "ubuntu_codename": "noble"},
    "debian-12": {"id": "debian", "version_id": "12", "version_codename": "bookworm"},
    "debian-13": {"id": "debian", "version_id": "13", "version_codename": "trixie"},
    "mint-22": {"id": "linuxmint", "id_like": "ubuntu debian", "version_id": "22", "version_codename": "wilma", "ubuntu_codename": "noble"},
}


def snapshot_lines(snap: Snapshot) -> list[str]:
    """The snapshot script's output for a given host state (inverse of parse)."""
    os_text = "".join(f'{k.upper()}="{v}"\n' for k, v in snap.os_release.items())
    lines = [f"os\t{base64.b64encode(os_text.encode()).decode()}", f"arch\t{snap.arch}"]
    for name, version in snap.packages.items():
        lines.append(f"pkg\t{name}\tinstall ok installed\t{version}")
    for path, state in snap.files.items():
        if state is None:
            lines.append(f"file\t{path}\tnone")
        else:
            lines.append(f"file\t{path}\t{state.kind}\t{state.sha256 or '-'}\t{state.mode} {state.owner} {state.group}")
    for user, groups in snap.users.items():
        lines.append(f"user\t{user}\t{' '.join(groups) if groups is not None else '-'}")
    for unit, (enabled, active) in snap.units.items():
        lines.append(f"unit\t{unit}\t{enabled}\t{active}")
    for command, path in snap.commands.items():
        lines.append(f"cmd\t{command}\t{path or ''}")
    for name, output in snap.probes.items():
        lines.append(f"probe\t{name}\t{base64.b64encode(output.encode()).decode()}")
    return lines


def fresh_host(os_name: str, arch: str = "amd64", users=("ops",)) -> Snapshot:
    return Snapshot(
        os_release=dict(OS_RELEASES[os_name]),
        arch=arch,
        packages={"ca-certificates": "1", "curl": "1"},
        users={u: [u] for u in users},
        commands={"gpg": "/usr/bin/gpg", "python3": "/usr/bin/python3", "systemd-run": "/usr/bin/systemd-run"},
    )


class Plan(dict):
    """Host name -> commands sent after the snapshot; ``failed``: host names."""

    failed: set[str]


def plan(hosts: dict[str, tuple[str, dict, Snapshot]], run: bool = True) -> Plan:
    """hosts: name -> (group, host data, snapshot).  Returns name -> commands
    sent after the snapshot (raw, unmasked), and which hosts failed."""
    from pyinfra_cli.util import load_deploy_file

    defaults = read_group_data()
    groups: dict[str, tuple[list, dict]] = {"robots": ([], defaults["robots"]), "laptops": ([], defaults["laptops"])}
    for name, (group, data, snap) in hosts.items():
        # Our deliberate failures (operations.fail) exit 1 on a real shell.
        responses = {SNAPSHOT_MARK: snapshot_lines(snap), re.compile(r">&2; exit 1'$"): {"stdout": [], "success": False}}
        host_data = {**data, "fake_responses": responses, "fake_delay": 0, "fake_delay_jitter": 0}
        groups[group][0].append((f"@fake/{name}", host_data))
    names = [name for members, _ in groups.values() for name, _ in members]
    inventory = Inventory((names, defaults["all"]), **groups)
    state = State(inventory=inventory, config=Config())
    state.cwd = str(ROOT)
    with ctx_state.use(state):
        connect_all(state)
        load_deploy_file(state, str(ROOT / "deploy.py"))
        if run:
            try:
                run_ops(state)
            except PyinfraError as error:
                if "No hosts remaining" not in str(error):
                    raise
        result = Plan()
        for host in inventory:
            commands = [c for c in host.connector.executed_commands if SNAPSHOT_MARK not in c]
            result[host.name.removeprefix("@fake/")] = commands
        result.failed = {h.name.removeprefix("@fake/") for h in state.failed_hosts}
        disconnect_all(state)
    return result


def find(commands: list[str], pattern: str) -> list[str]:
    return [c for c in commands if re.search(pattern, c)]


__all__ = ["FileState", "Snapshot", "fresh_host", "plan", "find", "OS_RELEASES"]
