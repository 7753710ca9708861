"""Enroll pull robots from their reports: their host keys into the fleet's known_hosts, their own key on the git server.

    robotfleet pull-enroll INVENTORY [--limit robot4] [--remote URL] [--admin URL --admin-key FILE] [--ssh]

A pull robot reports its SSH host keys and its key for the fleet remote
(refs/reports/<robot>; the robot signs nothing, the git server's rules say
only that robot's key could have written that ref).  For each pull robot
of the inventory this writes the host keys to the robot's
ssh_known_hosts_file (a key already there is left alone; a changed key is
refused with both fingerprints, as robotfleet enroll does): later pushes
and SSH need no trust-on-first-use.  With --admin (a gitolite you
administer) the robot's own key is registered and its first-boot
enrollment key removed.  A robot installed by a push deploy cannot report
before its key is registered: --ssh reads that key over SSH instead (the
host must then already be enrolled with robotfleet enroll).
"""

from __future__ import annotations

import base64
import os
import sys

import paramiko

from robotfleet import commands, hostkeys
from robotfleet.checkers import one_line
from robotfleet import selection
from robotfleet.commands import pullstatus
from robotfleet.commands.bundle import add_admin, admin_of, repository_name
from robotfleet.pull import gitolite, layout


def key_of(line: str):
    kind, data = line.split()[:2]
    return paramiko.PKey.from_type_string(kind, base64.b64decode(data))


def host_keys(name: str, data, lines: list[str]) -> list[str]:
    """Write ``lines`` (the robot's reported host keys) for its address; one line each."""
    path = os.path.expanduser(data.get("ssh_known_hosts_file") or "~/.ssh/known_hosts")
    entry = hostkeys.entry(data.get("ssh_hostname") or name, int(data.get("ssh_port") or 22))
    there = hostkeys.known(path, entry)
    said, new = [], []
    for line in lines:
        key = key_of(line)
        shown = f"{name} ({entry}) {key.get_name()} {hostkeys.fingerprint(key)}"
        if there.get(key.get_name()) == key:
            said.append(f"{shown}: already in {path}")
        elif key.get_name() in there:
            said.append(f"{name}: host key CHANGED for {entry}: {path} has {hostkeys.fingerprint(there[key.get_name()])}, "
                        f"the report says {hostkeys.fingerprint(key)}; refused, its line is left as it is")
        else:
            new.append((entry, key))
            said.append(f"{shown}: from its report; enrolled in {path}")
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
            ok, output = host.run_shell_command(StringCommand(f"cat {layout.KEY}.pub"), _sudo=True)
            found[host.name] = output.stdout.strip() if ok else f"error: no {layout.KEY}.pub (pull role not run?)"
    return found


def main(argv=None) -> int:
    parser = commands.parser("pull-enroll", __doc__)
    commands.add_inventory(parser)
    parser.add_argument("--limit", action="append", default=[], help="host name pattern or group (repeatable)")
    parser.add_argument("--remote", metavar="NAME|URL", help="the fleet remote (default: the checkout's origin)")
    parser.add_argument("--ssh", action="store_true", help="read the key of robots without a report over SSH")
    add_admin(parser)
    args = parser.parse_args(argv)
    args.inventory = commands.inventory_of(parser, args)
    try:
        admin = admin_of(args)
        inventory = selection.inventory(args.inventory)
        chosen = [h for h in selection.select(inventory, args.inventory, args.limit) if h.data.get("pull")]
        if not chosen:
            raise selection.Refused(f"{args.inventory}: no pull robot (pull: true) to enroll")
        url = pullstatus.remote_of(args.remote)
        found = pullstatus.fetch(url)
    except (selection.Refused, pullstatus.ReportsUnavailable) as error:
        return selection.refused(selection.Refused(str(error)))
    code = selection.OK
    unreported = [h for h in chosen if not found.get(h.name) or "error" in found[h.name]]
    over_ssh = keys_over_ssh(inventory, unreported) if args.ssh and unreported else {}
    for host in chosen:
        report = found.get(host.name)
        if report and "error" not in report:
            lines = host_keys(host.name, host.data, report.get("host_keys") or [])
            code = max(code, selection.FAILED if any("CHANGED" in line for line in lines) else selection.OK)
            for line in lines:
                print(one_line(line))
            key = report.get("key")
        elif args.ssh:
            key = over_ssh.get(host.name, "")
            if key.startswith("error: "):
                print(one_line(f"{host.name}: no report, and over SSH: {key[len('error: '):]}"), file=sys.stderr)
                code = max(code, selection.UNREACHABLE)
                continue
        else:
            print(f"{host.name}: no report in refs/reports/{host.name} of {url} (--ssh reads its key over SSH)",
                  file=sys.stderr)
            code = max(code, selection.UNREACHABLE)
            continue
        if not key:
            print(f"{host.name}: no key for the fleet remote yet", file=sys.stderr)
            continue
        if admin is None:
            print(f"{host.name}: its key for the fleet remote: {key}")
            continue
        try:
            changed = gitolite.register(admin, repository_name(host.data.get("pull_remote")), host.name, key)
        except gitolite.GitoliteError as error:
            print(f"{host.name}: {error}", file=sys.stderr)
            code = max(code, selection.FAILED)
            continue
        print(f"{host.name}: its own key is {'now registered' if changed else 'registered'} with {args.admin}"
              " (an enrollment key, if any, removed)")
    return code
