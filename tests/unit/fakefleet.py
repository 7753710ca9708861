"""Run deploy.py through pyinfra against @fake hosts and return what each
host would be sent: every command with its stdin (file contents and secrets
travel over stdin).

A test describes a host's state as a ``Snapshot`` of plain dicts; the harness
answers the snapshot command with only the keys the roles declared (the
production parser then refuses any other read), so a role that stops
declaring a read fails here as it would misbehave on a real host."""

from __future__ import annotations

import base64
import re
import shlex
from pathlib import Path

from pyinfra.api import Config, Inventory, State
from pyinfra.api.exceptions import PyinfraError
from pyinfra.api.connect import connect_all, disconnect_all
from pyinfra.api.operations import run_ops
from pyinfra.connectors.fake import FakeConnector
from pyinfra.context import ctx_state

from roles import hoststate
from roles import fleet
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


def query_of(snap: Snapshot) -> dict:
    """A query asking for everything ``snap`` holds."""
    return {kind: list(getattr(snap, kind)) for kind in hoststate.READING_KINDS}


def snapshot_lines(snap: Snapshot, query: dict) -> list[str]:
    """What the snapshot script prints for ``query`` on a host in state
    ``snap`` (the inverse of parse): queried keys only, as a real host would;
    a queried probe the test did not set prints nothing (empty output)."""

    def asked(kind):
        return [key for key in getattr(snap, kind) if key in set(query.get(kind) or ())]

    os_text = "".join(f'{k.upper()}="{v}"\n' for k, v in snap.os_release.items())
    lines = [f"os\t{base64.b64encode(os_text.encode()).decode()}", f"arch\t{snap.arch}"]
    for name in asked("packages"):
        lines.append(f"pkg\t{name}\tinstall ok installed\t{snap.packages[name]}")
    for path in query.get("files") or ():
        state = snap.files.get(path)
        if state is None:
            lines.append(f"file\t{path}\tnone")
        else:
            lines.append(f"file\t{path}\t{state.kind}\t{state.sha256 or '-'}\t{state.mode} {state.owner} {state.group}")
    for user in query.get("users") or ():
        groups = snap.users.get(user)
        lines.append(f"user\t{user}\t{' '.join(groups) if groups is not None else '-'}")
    for unit in query.get("units") or ():
        enabled, active = snap.units.get(unit, ("disabled", "inactive"))
        lines.append(f"unit\t{unit}\t{enabled}\t{active}")
    for command in query.get("commands") or ():
        lines.append(f"cmd\t{command}\t{snap.commands.get(command) or ''}")
    for name in query.get("probes") or ():
        output = snap.probes.get(name, "")
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


class Sent(str):
    """A command as sent to a host (raw, unmasked), with its ``stdin`` text."""

    stdin: str

    def __new__(cls, command: str, stdin: str = ""):
        sent = super().__new__(cls, command)
        sent.stdin = stdin
        return sent


def stdin_text(stdin) -> str:
    """The bytes pyinfra writes for ``_stdin`` (connectors.util.write_stdin), as text."""
    if stdin is None:
        return ""
    if hasattr(stdin, "readlines"):
        stdin = stdin.readlines()
    if not isinstance(stdin, (list, tuple)):
        stdin = [stdin]
    return "".join(line if line.endswith("\n") else f"{line}\n" for line in stdin)


class Plan(dict):
    """Host name -> commands (``Sent``) sent after the snapshot; ``failed``:
    host names; ``queries``: host name -> what its snapshot asked for."""

    failed: set[str]
    queries: dict[str, dict]


class _Recorder:
    """Patches, for one plan: the snapshot fact notes its query per host, and
    the @fake connector answers it from the host's ``Snapshot`` and records
    every other command with its stdin."""

    def __init__(self, snapshots: dict[str, Snapshot], contents: dict[str, dict[str, str]]):
        self.snapshots = snapshots
        self.contents = contents
        self.queries: dict[str, dict] = {}
        self.sent: dict[str, list[Sent]] = {name: [] for name in snapshots}

    def __enter__(self):
        recorder = self
        self._command, self._run = hoststate.HostSnapshot.command, FakeConnector.run_shell_command

        def command(self, files=(), packages=(), users=(), units=(), commands=(), probes=None):
            from pyinfra import host

            script = recorder._command(self, files, packages, users, units, commands, probes)
            recorder.queries[host.name.removeprefix("@fake/")] = self.query
            return script

        def run_shell_command(connector, command, print_output=False, print_input=False, **arguments):
            name = connector.host.name.removeprefix("@fake/")
            text = command if isinstance(command, str) else command.get_raw_value()
            if SNAPSHOT_MARK in text:
                return True, _output(snapshot_lines(recorder.snapshots[name], recorder.queries[name]))
            recorder.sent[name].append(Sent(text, stdin_text(arguments.get("_stdin"))))
            read = re.match(r"^\( test -e (\S+) && cat \1 \) \|\| echo ", text)  # FileContents
            if read:
                path = shlex.split(read.group(1))[0]
                if path in recorder.contents.get(name, {}):
                    return True, _output(recorder.contents[name][path].splitlines())
            return recorder._run(connector, command, print_output, print_input, **arguments)

        hoststate.HostSnapshot.command = command
        FakeConnector.run_shell_command = run_shell_command
        return self

    def __exit__(self, *exc):
        hoststate.HostSnapshot.command = self._command
        FakeConnector.run_shell_command = self._run


def _output(lines: list[str]):
    from pyinfra.connectors.util import CommandOutput, OutputLine

    return CommandOutput([OutputLine("stdout", line) for line in lines])


def plan(
    hosts: dict[str, tuple[str, dict, Snapshot]],
    run: bool = True,
    deploy_file: str = "deploy.py",
    diff: bool = False,
    contents: dict[str, dict[str, str]] | None = None,
) -> Plan:
    """hosts: name -> (group, host data, snapshot).  Returns name -> commands
    sent after the snapshot (raw, unmasked), and which hosts failed.

    ``run=False`` stops after planning (what ``--dry`` does); ``diff`` is
    ``--diff``; ``contents``: host -> path -> the file's text on that host,
    for pyinfra's FileContents fact."""
    from pyinfra_cli.exceptions import UnexpectedExternalError
    from pyinfra_cli.util import load_deploy_file

    defaults = read_group_data()
    groups: dict[str, tuple[list, dict]] = {"robots": ([], defaults["robots"]), "laptops": ([], defaults["laptops"])}
    for name, (group, data, snap) in hosts.items():
        # Our deliberate failures (operations.fail) exit 1 on a real shell.
        responses = {re.compile(r">&2; exit 1'$"): {"stdout": [], "success": False}}
        host_data = {**data, "fake_responses": responses, "fake_delay": 0, "fake_delay_jitter": 0}
        groups[group][0].append((f"@fake/{name}", host_data))
    names = [name for members, _ in groups.values() for name, _ in members]
    inventory = Inventory((names, defaults["all"]), **groups)
    state = State(inventory=inventory, config=Config(DIFF=diff))
    state.cwd = str(ROOT)
    with ctx_state.use(state), _Recorder({name: snap for name, (_, _, snap) in hosts.items()}, contents or {}) as recorder:
        connect_all(state)
        try:
            load_deploy_file(state, str(ROOT / deploy_file))
        except UnexpectedExternalError as error:
            raise error.exception from None  # the deploy's own error (say, UndeclaredRead)
        if run:
            try:
                run_ops(state)
            except PyinfraError as error:
                if "No hosts remaining" not in str(error):
                    raise
        result = Plan(recorder.sent)
        result.queries = recorder.queries
        result.failed = {h.name.removeprefix("@fake/") for h in state.failed_hosts}
        disconnect_all(state)
    return result


def find(commands: list[str], pattern: str) -> list[str]:
    """Commands (the command line only) matching ``pattern``."""
    return [c for c in commands if re.search(pattern, c)]


def written_files(commands: list[Sent]) -> dict[str, str]:
    """Files the plan writes (operations.write_file_command): path -> the
    content decoded from the command's stdin."""
    written = {}
    for command in commands:
        match = re.search(r"dest=(\S+)\n", command)
        if match and "base64 -d" in command:
            written[shlex.split(match.group(1))[0]] = base64.b64decode(command.stdin).decode()
    return written


def everything_sent(commands: list[Sent]) -> str:
    """All a host receives: command lines, stdin, and decoded file contents."""
    parts = [f"{c}\n{c.stdin}" for c in commands]
    return "\n".join(parts + list(written_files(commands).values()))


def fleet_problems(doc, path: str = "robots.yaml") -> list[str]:
    """The problem lines the fleet check prints for ``doc`` ([] if accepted)."""
    try:
        fleet.check(doc, path, read_group_data())
    except fleet.FleetError as error:
        return error.lines
    return []


__all__ = ["fleet_problems", "FileState", "Snapshot", "Sent", "fresh_host", "plan", "find", "written_files", "everything_sent", "OS_RELEASES"]
