"""Enroll pull robots from their reports: their host keys into the fleet's known_hosts, their own key on the git server.

    robotfleet pull-enroll INVENTORY [--limit robot4] [--remote URL] [--admin URL --admin-key FILE] [--ssh]
                           [--fingerprints FILE] [--replace ROBOT]

A pull robot reports its SSH host keys and its key for the fleet remote
(refs/reports/<robot>).  Nothing in a report is taken on its word: its keys
are enrolled when the report is proven by the robot's first-boot bundle
(its enrollment key, whose hash robotfleet bundle kept, signed the robot's
name and keys: robotfleet/pull/protocol/enrollment.py), or match a fingerprints
file (--fingerprints: ``ROBOT SHA256:...`` lines listing every key the
report carries, as robotfleet enroll reads them), or the operator confirms
their fingerprints on a terminal; else the robot is refused, one line.
Its host keys are written to its ssh_known_hosts_file (a key already there
is left alone; a changed one is refused with both fingerprints), and the
hash of its own key is kept: a name reported later with another key is
refused until the operator names it with --replace ROBOT and gives its own
bundle's proof or --fingerprints (a shared image's proof says only that the
sender holds the image).  With --admin (a gitolite you administer) the
robot's own key is registered and its first-boot enrollment key removed.
A robot installed by a push deploy has no enrollment key: --ssh reads its
key over SSH instead (the host must then already be enrolled with
robotfleet enroll; its host keys are not taken from its report).
"""

from __future__ import annotations

import argparse
import base64
import os
import sys
from dataclasses import dataclass

import paramiko

import robotfleet
from robotfleet import commands, hostkeys, selection
from robotfleet.checkers import one_line
from robotfleet.commands import enroll
from robotfleet.commands.pull import status as pullstatus
from robotfleet.commands.pull.bundle import add_admin, admin_of, repository_name
from robotfleet.fleet import pull_mode
from robotfleet.pull.operator import enrollments, gitolite
from robotfleet.pull.protocol import agent_files, enrollment, report_shards


def key_of(line: str):
    kind, data = line.split()[:2]
    return paramiko.PKey.from_type_string(kind, base64.b64decode(data))


def shown(line: str) -> str:
    """A key line as its type and fingerprint."""
    key = key_of(line)
    return f"{key.get_name()} {hostkeys.fingerprint(key)}"


def host_keys(name: str, data, lines: list[str], replace: bool = False) -> list[str]:
    """Write ``lines`` (the robot's reported host keys) for its address; one
    line each.  ``replace``: a changed key replaces the ones there."""
    path = os.path.expanduser(data.get("ssh_known_hosts_file") or "~/.ssh/known_hosts")
    entry = hostkeys.entry(data.get("ssh_hostname") or name, int(data.get("ssh_port") or 22))
    there = hostkeys.known(path, entry)
    keys = [key_of(line) for line in lines]
    if replace and keys and any(there.get(k.get_name()) not in (None, k) for k in keys):
        was = ", ".join(f"{kind} {hostkeys.fingerprint(k)}" for kind, k in there.items())
        hostkeys.replace(path, entry, keys[0])
        hostkeys.add_all(path, [(entry, k) for k in keys[1:]])
        now = ", ".join(f"{k.get_name()} {hostkeys.fingerprint(k)}" for k in keys)
        return [f"{name} ({entry}): host keys replaced in {path} (--replace): was {was}, now {now}"]
    said, new = [], []
    for key in keys:
        head = f"{name} ({entry}) {key.get_name()} {hostkeys.fingerprint(key)}"
        if there.get(key.get_name()) == key:
            said.append(f"{head}: already in {path}")
        elif key.get_name() in there:
            said.append(
                f"{name}: host key CHANGED for {entry}: {path} has "
                f"{hostkeys.fingerprint(there[key.get_name()])}, the report says {hostkeys.fingerprint(key)}; "
                "refused, its line is left as it is"
            )
        else:
            new.append((entry, key))
            said.append(f"{head}: from its report; enrolled in {path}")
    hostkeys.add_all(path, new)
    return said


def keys_over_ssh(inventory, hosts) -> dict[str, str]:
    """name -> the robot's key for the fleet remote, read over SSH (or why not)."""
    from pyinfra.api import Config, State
    from pyinfra.api.command import StringCommand
    from pyinfra.api.exceptions import ConnectError
    from pyinfra.context import ctx_state

    state = State(inventory=inventory, config=Config(CONNECT_TIMEOUT=10), check_for_changes=False)
    state.limit_hosts = hosts
    found = {}
    with ctx_state.use(state):
        for host in hosts:
            try:
                host.connect(raise_exceptions=True, show_errors=False)
            except ConnectError as error:
                found[host.name] = f"error: {error.args[0]}"
                continue
            ok, output = host.run_shell_command(StringCommand(f"cat {agent_files.KEY}.pub"), _sudo=True)
            found[host.name] = output.stdout.strip() if ok else f"error: no {agent_files.KEY}.pub (pull role not run?)"
    return found


@dataclass
class Asked:
    """What the operator gave: the inventory's path, the enrollments file and
    what it keeps, the fingerprints (and the file's name), --replace, --ssh."""

    inventory: str
    kept_path: str
    kept: dict
    expected: dict[str, set[str]] | None = None
    source: str | None = None
    replace: frozenset = frozenset()
    ssh: bool = False


def judge(host, report: dict, asked: Asked) -> tuple[str, str]:
    """How ``report``'s keys are trusted, and the line saying so: ("robot" |
    "shared" (a proof by its bundle's or a shared image's enrollment key),
    "listed", "known", "confirmed", "ssh" (read its key over SSH) or
    "refused", line)."""
    name, key, hosts = host.name, report.get("key"), report.get("host_keys") or []
    prints = [shown(line) for line in hosts] + ([f"own key {shown(key)}"] if key else [])
    try:
        proven = enrollments.verify(report, asked.kept, asked.kept_path)
        why = ""
    except enrollment.ProofError as error:
        proven, why = "", str(error)
    listed = enroll.recorded_for(enroll.target(host), asked.expected)
    if listed is not None:
        missing = [p for p in prints if p.split()[-1].rstrip("=") not in listed]
        if missing:
            return "refused", f"{name}: {'; '.join(missing)} from its report: not in {asked.source}; refused"
        how, line = "listed", f"{name}: its report's keys match {asked.source}"
    elif proven == "robot":
        how, line = proven, f"{name}: its report is proven by its bundle's enrollment key"
    elif proven == "shared":
        how, line = (
            proven,
            (
                f"{name}: its report is proven by a shared image's enrollment key (whoever holds a copy "
                "of the image could have sent it)"
            ),
        )
    else:
        how, line = "", ""
    enrolled = enrollments.enrolled_key(asked.kept, name)
    if key and enrolled and enrollment.key_sha256(key) != enrolled:
        head = f"{name}: reported with its own key {shown(key)}, but it was enrolled with another ({asked.kept_path})"
        if name not in asked.replace:
            return "refused", (
                f"{head}; refused: if {name} was reinstalled, robotfleet pull-enroll {asked.inventory} "
                f"--replace {name} with its new bundle's proof or --fingerprints FILE"
            )
        if how not in ("robot", "listed"):
            return "refused", (
                f"{head}; --replace {name} needs its own bundle's proof or --fingerprints FILE"
                f"{f' ({why})' if why else ''}; not replaced"
            )
        return how, f"{line}; it replaces the key {name} was enrolled with (--replace)"
    if how:
        return how, line
    path = os.path.expanduser(host.data.get("ssh_known_hosts_file") or "~/.ssh/known_hosts")
    there = hostkeys.known(path, enroll.target(host).entry)
    if key and enrolled and all(there.get(key_of(h).get_name()) == key_of(h) for h in hosts):
        return "known", f"{name}: its keys are the ones it was enrolled with"
    if asked.ssh:
        return "ssh", f"{name}: {why}: its key is read over SSH (--ssh), its host keys are not taken from the report"
    if sys.stdin.isatty():
        for line in prints:
            print(f"{name}: {line}", file=sys.stderr)
        if enroll.ask(f"{name}: {why}. Are these {name}'s keys (as its console shows them)? [y/N] "):
            return "confirmed", f"{name}: its keys, confirmed"
        return "refused", f"{name}: not enrolled"
    return "refused", (
        f"{name}: not enrolled: {why} ({', '.join(prints)}); give --fingerprints FILE with the "
        "fingerprints read on the robot, or confirm them on a terminal"
    )


def build_parser() -> argparse.ArgumentParser:
    """``robotfleet pullenroll``'s command line (the shell completion and the manual page read it too)."""
    parser = commands.parser("pull-enroll", __doc__)
    commands.add_inventory(parser)
    parser.add_argument("--limit", action="append", default=[], help=commands.LIMIT_HELP)
    parser.add_argument("--remote", metavar="NAME|URL", help="the releases remote (default: the one the fleet names)")
    parser.add_argument(
        "--ssh", action="store_true", help="read the key of robots without a report (or a proven one) over SSH"
    )
    parser.add_argument(
        "--fingerprints",
        metavar="FILE",
        help="the robots' recorded fingerprints: ROBOT SHA256:... per line, every key of its report",
    )
    parser.add_argument(
        "--replace",
        metavar="ROBOT",
        action="append",
        default=[],
        help="take ROBOT's new keys in place of those it was enrolled with, when proven by its own "
        "bundle or --fingerprints (repeatable)",
    )
    add_admin(parser)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    args.inventory = commands.inventory_of(parser, args)
    try:
        admin = admin_of(args)
        expected = enroll.read_fingerprints(args.fingerprints) if args.fingerprints else None
        inventory = selection.inventory(args.inventory)
        chosen = [h for h in selection.select(inventory, args.inventory, args.limit) if pull_mode.pulls(h.data)]
        if not chosen:
            raise selection.Refused(f"{args.inventory}: no pull robot (pull_enabled: true) to enroll")
        unknown = [name for name in args.replace if name not in {h.name for h in chosen}]
        if unknown:
            raise selection.Refused(
                f"--replace {' '.join(unknown)}: no such pull robot selected in {args.inventory}; nothing was done"
            )
        url = pullstatus.remote_of(args.remote, [(h.name, h.data) for h in chosen])
        shards = pullstatus.shards_of([(h.name, h.data) for h in chosen])
        found = pullstatus.fetch(url, shards=shards)
    except (OSError, ValueError) as error:
        return selection.refused(selection.Refused(one_line(str(error))))
    except (selection.Refused, pullstatus.ReportsUnavailable) as error:
        return selection.refused(selection.Refused(str(error)))
    path = enrollments.kept_file(robotfleet.CHECKOUT)
    asked = Asked(
        args.inventory,
        str(path),
        enrollments.read_kept(path),
        expected,
        args.fingerprints,
        frozenset(args.replace),
        args.ssh,
    )
    code = selection.OK
    verdicts = {}
    for host in chosen:
        report = found.get(host.name)
        if report and "error" not in report:
            try:
                verdicts[host.name] = judge(host, report, asked)
            except (paramiko.SSHException, ValueError) as error:  # a key line that is no key
                verdicts[host.name] = ("refused", f"{host.name}: its report's keys cannot be read ({error}); refused")
    unreported = [h for h in chosen if h.name not in verdicts or verdicts[h.name][0] == "ssh"]
    over_ssh = keys_over_ssh(inventory, unreported) if args.ssh and unreported else {}
    for host in chosen:
        report = found.get(host.name)
        how, said = verdicts.get(host.name, ("", ""))
        if said:
            print(one_line(said), file=sys.stderr if how == "refused" else sys.stdout)
        if how == "refused":
            code = max(code, selection.FAILED)
            continue
        if how and how != "ssh":
            lines = host_keys(host.name, host.data, report.get("host_keys") or [], host.name in asked.replace)
            changed = any("CHANGED" in line for line in lines)
            for line in lines:
                print(one_line(line), file=sys.stderr if "CHANGED" in line else sys.stdout)
            if changed:
                code = max(code, selection.FAILED)
                continue
            key = report.get("key")
        elif args.ssh:
            key = over_ssh.get(host.name, "")
            if key.startswith("error: "):
                print(
                    one_line(
                        f"{host.name}: {'no report' if not how else 'no proof'}, and over SSH: {key[len('error: ') :]}"
                    ),
                    file=sys.stderr,
                )
                code = max(code, selection.UNREACHABLE)
                continue
            enrolled = enrollments.enrolled_key(asked.kept, host.name)
            if key and enrolled and enrollment.key_sha256(key) != enrolled and host.name not in asked.replace:
                print(
                    f"{host.name}: its key over SSH is not the one it was enrolled with ({path}); refused "
                    f"(--replace {host.name} takes it)",
                    file=sys.stderr,
                )
                code = max(code, selection.FAILED)
                continue
        else:
            print(
                f"{host.name}: no report in refs/reports/{host.name} of "
                f"{report_shards.report_url(url, host.name, shards)} (--ssh reads its key over SSH)",
                file=sys.stderr,
            )
            code = max(code, selection.UNREACHABLE)
            continue
        if not key:
            print(f"{host.name}: no key for the fleet remote yet", file=sys.stderr)
            continue
        if enrollments.enrolled_key(asked.kept, host.name) != enrollment.key_sha256(key):
            enrollments.record(path, host.name, key)
        if admin is None:
            print(f"{host.name}: its key for the fleet remote: {key}")
            continue
        remote = pull_mode.value(host.data, "pull_remote")
        try:
            changed = gitolite.register(admin, repository_name(remote), host.name, key, shards=shards)
        except gitolite.GitoliteError as error:
            print(f"{host.name}: {error}", file=sys.stderr)
            code = max(code, selection.FAILED)
            continue
        print(
            f"{host.name}: its own key is {'now registered' if changed else 'registered'} with {args.admin}"
            " (an enrollment key, if any, removed)"
        )
    return code
