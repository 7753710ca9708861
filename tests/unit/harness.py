"""The unit layer's one harness, built from the roles deploy.py lists.

- ``plan``: run deploy.py through pyinfra against @fake hosts and return what
  each host would be sent: every command with its stdin (file contents and
  secrets travel over stdin).  A test describes a host's state as a
  ``Snapshot`` of plain dicts; the harness answers the snapshot command with
  only the keys the roles declared (the production parser then refuses any
  other read), so a role that stops declaring a read fails here as it would
  misbehave on a real host.
- ``merged`` and ``converged``: a host's data with every default, and the
  snapshot of a host on which a previous run succeeded, from each running
  role's ``fixtures.converged`` (roles/<name>/fixtures.py): adding a role
  needs no edit here or in another role's tests.
- ``parse``, ``check``, ``load``, ``fleet_problems``: the fleet file checked
  against deploy.py's roles."""

from __future__ import annotations

import base64
import contextlib
import importlib
import re
import shlex

import pyinfra
from pyinfra.api import Config, Inventory, State
from pyinfra.api.connect import connect_all, disconnect_all
from pyinfra.api.exceptions import PyinfraError
from pyinfra.api.operations import run_ops
from pyinfra.api.state import StateStage
from pyinfra.connectors.fake import FakeConnector
from pyinfra.context import ctx_state

from robotfleet import deploy_roles
from robotfleet.fleet import validate as fleet_check
from robotfleet.host import aptrepo
from robotfleet.host import snapshot as hoststate
from robotfleet.host.snapshot import FileState, Snapshot
from robotfleet.role import Play, added
from roles.payload import compose, hooks, release, services
from tests.fixtures import IMAGE, ROOT

# Sample hosts most tests start from.
ROBOT = {
    "payload_image": IMAGE,
    "docker_users": ["ops"],
    "udev_sensors": [
        {
            "name": "front_camera",
            "subsystem": "video4linux",
            "vendor_id": "046d",
            "product_id": "0825",
            "usb_port": "1-1.2",
        },
        {"name": "lidar", "subsystem": "tty", "serial": "0001A2B3"},
    ],
}
LAPTOP = {"payload_image": IMAGE, "docker_users": ["alice"], "x11_user": "alice"}
SNAPSHOT_MARK = "export LC_ALL=C"

OS_RELEASES = {
    "ubuntu-20.04": {
        "id": "ubuntu",
        "id_like": "debian",
        "version_id": "20.04",
        "version_codename": "focal",
        "ubuntu_codename": "focal",
    },
    "ubuntu-22.04": {
        "id": "ubuntu",
        "id_like": "debian",
        "version_id": "22.04",
        "version_codename": "jammy",
        "ubuntu_codename": "jammy",
    },
    "ubuntu-24.04": {
        "id": "ubuntu",
        "id_like": "debian",
        "version_id": "24.04",
        "version_codename": "noble",
        "ubuntu_codename": "noble",
    },
    "debian-12": {"id": "debian", "version_id": "12", "version_codename": "bookworm"},
    "debian-13": {"id": "debian", "version_id": "13", "version_codename": "trixie"},
    "mint-22": {
        "id": "linuxmint",
        "id_like": "ubuntu debian",
        "version_id": "22",
        "version_codename": "wilma",
        "ubuntu_codename": "noble",
    },
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

    lines = [f'osl\t{k.upper()}="{v}"' for k, v in snap.os_release.items()] + [f"arch\t{snap.arch}"]
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
    host names; ``queries``: host name -> what its snapshot asked for;
    ``changes``: host name -> the operations planning found would change it,
    the conditional ones (``_if``) left out (what ``--dry --json`` lists as
    ``hosts_with_change``)."""

    failed: set[str]
    queries: dict[str, dict]
    changes: dict[str, list[str]]


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


@contextlib.contextmanager
def _as_the_cli():
    """Operations identified as the pyinfra CLI identifies them: by the line
    numbers of their call stack (the API counts per host instead), so that
    roles whose operations share line numbers, run on different hosts, make
    the same "Cycle detected in operation ordering DAG" they make for real."""
    before = pyinfra.is_cli
    pyinfra.is_cli = True
    try:
        yield
    finally:
        pyinfra.is_cli = before


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

    defaults = group_data()
    groups: dict[str, tuple[list, dict]] = {"robots": ([], defaults["robots"]), "laptops": ([], defaults["laptops"])}
    for name, (group, data, _) in hosts.items():
        # Our deliberate failures (operations.fail) exit 1 on a real shell.
        responses = {re.compile(r">&2; exit 1'$"): {"stdout": [], "success": False}}
        host_data = {**data, "fake_responses": responses, "fake_delay": 0, "fake_delay_jitter": 0}
        groups[group][0].append((f"@fake/{name}", host_data))
    names = [name for members, _ in groups.values() for name, _ in members]
    inventory = Inventory((names, defaults["all"]), **groups)
    state = State(inventory=inventory, config=Config(DIFF=diff))
    state.cwd = str(ROOT)
    with (
        ctx_state.use(state),
        _Recorder({name: snap for name, (_, _, snap) in hosts.items()}, contents or {}) as recorder,
        _as_the_cli(),
    ):
        state.set_stage(StateStage.Connect)
        connect_all(state)
        state.set_stage(StateStage.Prepare)
        try:
            load_deploy_file(state, str(ROOT / deploy_file))
        except UnexpectedExternalError as error:
            raise error.exception from None  # the deploy's own error (say, UndeclaredRead)
        if run:
            state.set_stage(StateStage.Execute)
            try:
                run_ops(state)
            except PyinfraError as error:
                if "No hosts remaining" not in str(error):
                    raise
        result = Plan(recorder.sent)
        result.queries = recorder.queries
        result.changes = {
            host.name.removeprefix("@fake/"): [
                ", ".join(sorted(state.op_meta[op_hash].names))
                for op_hash, op in state.ops[host].items()
                if op.operation_meta._maybe_is_change and not op.global_arguments["_if"]
            ]
            for host in state.inventory
        }
        result.failed = {h.name.removeprefix("@fake/") for h in state.failed_hosts}
        disconnect_all(state)
    return result


def find(commands: list[str], pattern: str) -> list[str]:
    """Commands (the command line only) matching ``pattern``."""
    return [c for c in commands if re.search(pattern, c)]


def written_files(commands: list[Sent]) -> dict[str, str | bytes]:
    """Files the plan writes (operations.write_file_command): path -> the
    content decoded from the command's stdin (bytes where it is not text:
    the payloadctl zip application)."""
    written = {}
    for command in commands:
        match = re.search(r"dest=(\S+)\n", command)
        if match and "base64 -d" in command:
            content = base64.b64decode(command.stdin)
            try:
                content = content.decode()
            except UnicodeDecodeError:
                pass
            written[shlex.split(match.group(1))[0]] = content
    return written


def everything_sent(commands: list[Sent]) -> str:
    """All a host receives: command lines, stdin, and decoded file contents."""
    parts = [f"{c}\n{c.stdin}" for c in commands]
    files = [
        content if isinstance(content, str) else content.decode("latin-1")
        for content in written_files(commands).values()
    ]
    return "\n".join(parts + files)


# --- the fleet file ------------------------------------------------------------

FleetError = fleet_check.FleetError
display_path = fleet_check.display_path


def registry():
    return deploy_roles.registry()


def setting_checks() -> dict:
    """Every setting's checker, by name."""
    return {name: setting.check for name, setting in registry().settings.items()}


def group_data() -> dict[str, dict]:
    """What pyinfra reads from group_data/, by group."""
    return {group: deploy_roles.group_data(group) for group in ("all", "robots", "laptops")}


def parse(text, shown: str = "f.yaml"):
    return fleet_check.parse(text, shown, registry())


def check(doc, shown: str = "f.yaml"):
    return fleet_check.check(doc, shown, registry())


def load(path):
    return fleet_check.load(path, registry())


def fleet_problems(doc, path: str = "robots.yaml") -> list[str]:
    """The problem lines the fleet check prints for ``doc`` ([] if accepted)."""
    try:
        check(doc, path)
    except FleetError as error:
        return error.lines
    return []


# --- hosts: data and snapshots ------------------------------------------------


class Data(dict):
    """A host's data, read as pyinfra's host.data is."""

    __getattr__ = dict.__getitem__


def merged(group: str, data: dict) -> Data:
    """``data`` over every default of ``group``, as a host in it sees it."""
    defaults = group_data()
    return Data({**defaults["all"], **defaults[group], **data})


def running_roles(data) -> tuple:
    return tuple(role for role in deploy_roles.roles() if role.runs_on(data))


def converged(group: str, data: dict, os_name: str, arch: str = "amd64", name: str | None = None) -> Snapshot:
    """The snapshot of host ``name`` (default r1 or l1 by group) on which a
    previous run succeeded: each role that runs there fills in what it
    leaves behind (roles/<name>/fixtures.py)."""
    d = merged(group, data)
    snap = fresh_host(os_name, arch, users=())
    play = Play(d, snap, running_roles(d))
    host = "@fake/" + (name or ("r1" if group == "robots" else "l1"))
    for role in play.roles:
        importlib.import_module(f"roles.{role.name}.fixtures").converged(play, host)
    return snap


def desired_compose(data, address: str) -> dict:
    """The compose document the deploy computes for a host with ``data``
    (what the roles running there add included)."""
    return compose.project(data, address, added(running_roles(data), hooks.SERVICES, data, services.declared(data)))


def release_spec(data, doc: dict) -> dict:
    """The spec the deploy hands payloadctl for ``doc``."""
    return release.spec(data, doc, added(running_roles(data), hooks.CHECKS, data))


def docker_repo(url: str, key_path: str, fingerprint: str | None, sha256: str | None = None) -> aptrepo.Repository:
    """Docker's repository as the docker role declares it, for the key script's own tests."""
    return aptrepo.Repository(
        "Docker",
        url,
        key_path,
        fingerprint,
        "docker_apt_key_fingerprint",
        "docker",
        "",
        "docker_key_fingerprints",
        sha256,
        "docker_apt_key_sha256",
    )


__all__ = [
    "fleet_problems",
    "FileState",
    "Snapshot",
    "Sent",
    "fresh_host",
    "plan",
    "find",
    "written_files",
    "everything_sent",
    "OS_RELEASES",
    "merged",
    "converged",
    "parse",
    "check",
    "load",
    "group_data",
    "Data",
    "IMAGE",
    "ROBOT",
    "LAPTOP",
    "desired_compose",
    "release_spec",
    "docker_repo",
]
