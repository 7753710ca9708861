"""First contact: enroll robots' SSH host keys into the fleet's known_hosts.

    robotfleet enroll inventories/robots.py [--limit robot1] [--fingerprints FILE [--allow-unlisted]] [--yes]
    robotfleet enroll inventories/robots.py --replace robot1 --fingerprints FILE

For each host of the inventory (or of --limit) this fetches the host key the
host offers (no login) and shows its fingerprint as ssh shows it
(SHA256:...).  A new key is written to the host's ssh_known_hosts_file once
you accept it: asked for each host, or checked against a fingerprints file
(one ``HOST SHA256:...`` per line, HOST the inventory name, the address or
``[address]:port``: what a vendor or an image build recorded), or accepted
as shown with --yes.  With a fingerprints file, a host missing from it is
refused, --yes or not, unless --allow-unlisted (then it is asked for, or
taken with --yes).  A key already there is left alone; a key that differs
from the one there is refused with both fingerprints and its line left as it
is, unless the host is named by --replace (a reflashed robot) and its new key
matches the fingerprints file: then its old line is replaced, and both
fingerprints are shown.  Hosts reached through a jump host (ssh_config
ProxyJump) are contacted directly here, which may not work: enroll them from
their fingerprints with ssh-keyscan on the jump host.
"""

from __future__ import annotations

import argparse
import os
import re
import socket
import sys
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass

import paramiko

from robotfleet import commands, connect, hostkeys, reasons, selection
from robotfleet.checkers import one_line
from robotfleet.commands import progressline

# The summary's word for each outcome (decide's outcomes are verbs).
SAID = {"enroll": "enrolled", "replace": "replaced"}


@dataclass
class Target:
    name: str
    address: str
    port: int
    known_hosts: str
    timeout: int

    @property
    def entry(self) -> str:
        return hostkeys.entry(self.address, self.port)


def target(host) -> Target:
    data = host.data
    return Target(
        host.name,
        data.get("ssh_hostname") or host.name,
        int(data.get("ssh_port") or 22),
        os.path.expanduser(data.get("ssh_known_hosts_file") or "~/.ssh/known_hosts"),
        int(data.get("ssh_connect_timeout") or 10),
    )


def fetch(host: Target):
    """The host key ``host`` offers, or the reason it could not be had (str)."""
    transport = None
    try:
        sock = socket.create_connection((host.address, host.port), timeout=host.timeout)
        transport = paramiko.Transport(sock)
        transport.set_log_channel(connect.PARAMIKO_LOG)
        transport.banner_timeout = host.timeout
        transport.start_client(timeout=host.timeout)
        return transport.get_remote_server_key()
    except Exception as error:  # every way it fails is one line
        return reasons.network_reason(
            error, host.address, host.port, host.timeout, greeted=reasons.greeting_seen(transport)
        )[0]
    finally:
        if transport is not None:
            transport.close()


# A SHA256 fingerprint as ssh-keygen -l shows it: 32 bytes in unpadded base64, 43 characters.
FINGERPRINT = re.compile(r"SHA256:[A-Za-z0-9+/]{43}=?")


def read_fingerprints(path: str) -> dict[str, set[str]]:
    """HOST -> fingerprints, from lines ``HOST [type] SHA256:...`` (# comments)."""
    found: dict[str, set[str]] = {}
    try:
        with open(path, encoding="utf-8") as handle:
            lines = handle.read().splitlines()
    except (OSError, UnicodeDecodeError) as error:
        why = error.strerror if isinstance(error, OSError) else "not UTF-8 text"
        raise ValueError(
            f"--fingerprints {path}: {why}; give the file of the hosts' recorded fingerprints "
            "(HOST SHA256:... a line); nothing was done"
        ) from None
    for number, line in enumerate(lines, 1):
        words = line.split("#", 1)[0].split()
        if not words:
            continue
        prints = [w for w in words[1:] if w.startswith("SHA256:")]
        if not prints:
            raise ValueError(
                f"{path}: line {number}: expected 'HOST SHA256:...', got {line.strip()!r}; nothing was done"
            )
        bad = next((p for p in prints if not FINGERPRINT.fullmatch(p)), None)
        if bad:
            raise ValueError(
                f"{path}: line {number}: {bad!r} is not a SHA256 fingerprint (SHA256: and 43 base64 "
                "characters, as ssh-keygen -lf shows it); nothing was done"
            )
        found.setdefault(words[0], set()).update(p.rstrip("=") for p in prints)
    return found


def ask(question: str) -> bool:
    print(question, end="", file=sys.stderr, flush=True)
    try:
        return input().strip().lower() in ("y", "yes")
    except EOFError:
        return False


@dataclass
class Choices:
    """What the operator asked for: the recorded fingerprints (and the
    file's name), --yes, --allow-unlisted, the hosts named by --replace."""

    expected: dict[str, set[str]] | None = None
    source: str | None = None
    yes: bool = False
    allow_unlisted: bool = False
    replace: frozenset = frozenset()
    inventory: str = "INVENTORY"


def recorded_for(host: Target, expected: dict[str, set[str]] | None) -> set[str] | None:
    if expected is None:
        return None
    return next((expected[n] for n in (host.name, host.address, host.entry) if n in expected), None)


def changed(host: Target, key, there: dict, choices: Choices) -> tuple[str, str]:
    """A host whose key differs from the one in known_hosts: replaced only
    when --replace names it and the new key matches the recorded fingerprint."""
    old = ", ".join(f"{kind} {hostkeys.fingerprint(k)}" for kind, k in there.items())
    new = f"{key.get_name()} {hostkeys.fingerprint(key)}"
    head = f"{host.name}: host key CHANGED for {host.entry}: {host.known_hosts} has {old}, the host offers {new}"
    if host.name not in choices.replace:
        return "refused", (
            f"{head}; refused, its line is left as it is ({reasons.replace_advice(choices.inventory, host.name)})"
        )
    recorded = recorded_for(host, choices.expected)
    if recorded is None:
        return "refused", f"{head}; not in {choices.source}: not replaced, its line is left as it is"
    if hostkeys.fingerprint(key) not in recorded:
        return "refused", (
            f"{head}; {choices.source} has {', '.join(sorted(recorded))}: not replaced, its line is left as it is"
        )
    return "replace", f"{host.name} ({host.entry}): host key replaced: was {old}, now {new} (matches {choices.source})"


def decide(host: Target, key, choices: Choices) -> tuple[str, str]:
    """(outcome, line): outcome is known, enroll, replace, refused or declined."""
    shown = f"{host.name} ({host.entry}) {key.get_name()} {hostkeys.fingerprint(key)}"
    there = hostkeys.known(host.known_hosts, host.entry)
    if there.get(key.get_name()) == key:
        return "known", f"{shown}: already in {host.known_hosts}"
    if there:
        return changed(host, key, there, choices)
    recorded = recorded_for(host, choices.expected)
    if recorded is not None:
        if hostkeys.fingerprint(key) in recorded:
            return "enroll", f"{shown}: matches {choices.source}; enrolled"
        return "refused", (
            f"{host.name}: fingerprint mismatch for {host.entry}: {choices.source} has "
            f"{', '.join(sorted(recorded))}, the host offers {hostkeys.fingerprint(key)}; refused"
        )
    if choices.expected is not None and not choices.allow_unlisted:
        return "refused", (
            f"{shown}: not in {choices.source}; refused (a host missing from the fingerprints file "
            "is enrolled only with --allow-unlisted)"
        )
    if choices.yes:
        return "enroll", f"{shown}: new; enrolled (--yes)"
    if not sys.stdin.isatty():
        return "declined", (
            f"{shown}: new; not enrolled: no terminal to ask (check the fingerprint, then pass "
            "--yes, or give --fingerprints FILE)"
        )
    if ask(f"{shown}: new. Is this the robot's key? [y/N] "):
        return "enroll", f"{shown}: enrolled"
    return "declined", f"{shown}: not enrolled"


def build_parser() -> argparse.ArgumentParser:
    """``robotfleet enroll``'s command line (the shell completion and the manual page read it too)."""
    parser = commands.parser("enroll", __doc__)
    commands.add_inventory(parser)
    parser.add_argument("--limit", action="append", default=[], help=commands.LIMIT_HELP)
    parser.add_argument(
        "--fingerprints", metavar="FILE", help="the hosts' recorded fingerprints: HOST SHA256:... per line"
    )
    parser.add_argument(
        "--allow-unlisted",
        action="store_true",
        help="with --fingerprints: hosts missing from FILE are asked for (or taken with --yes) instead of refused",
    )
    parser.add_argument(
        "--replace",
        metavar="HOST",
        action="append",
        default=[],
        help="replace HOST's changed key when the new one matches --fingerprints FILE (repeatable)",
    )
    parser.add_argument("-y", "--yes", action="store_true", help="enroll new keys as shown, without asking")
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    args.inventory = commands.inventory_of(parser, args)
    try:
        if args.replace and not args.fingerprints:
            raise selection.Refused(
                "--replace needs --fingerprints FILE: a changed key is replaced only when it "
                "matches the fingerprint recorded for the host; nothing was done"
            )
        expected = read_fingerprints(args.fingerprints) if args.fingerprints else None
        inventory = selection.inventory(args.inventory)
        names = [h.name for h in inventory]
        unknown = [name for name in args.replace if name not in names]
        if unknown:
            raise selection.Refused(
                f"--replace {' '.join(unknown)}: no such host in {args.inventory}; nothing was done"
            )
        limits = args.limit or args.replace  # --replace alone: only those hosts
        chosen = [target(h) for h in selection.select(inventory, args.inventory, limits) if not h.name.startswith("@")]
    except (OSError, ValueError) as error:
        return selection.refused(selection.Refused(one_line(str(error))))
    except selection.Refused as error:
        return selection.refused(error)
    choices = Choices(
        expected, args.fingerprints, args.yes, args.allow_unlisted, frozenset(args.replace), args.inventory
    )
    if not chosen:
        return selection.refused(
            selection.Refused(f"{args.inventory}: no SSH host to enroll (@local hosts have no host key)")
        )
    print(
        f"fetching the host keys of {len(chosen)} host(s) (at most {max(h.timeout for h in chosen)} s)...",
        file=sys.stderr,
    )
    with ThreadPoolExecutor(max_workers=min(32, len(chosen))) as pool, progressline.Line("enroll", len(chosen)) as line:
        jobs = {pool.submit(fetch, host): host for host in chosen}
        for job in as_completed(jobs):
            line.advance(failed=int(isinstance(job.result(), str)))
        keys = [job.result() for job in jobs]
    outcomes: dict[str, list[str]] = {}
    accepted: dict[str, list] = {}
    for host, key in zip(chosen, keys):
        if isinstance(key, str):
            outcome, line = "unreachable", f"{host.name}: unreachable: {key}"
        else:
            outcome, line = decide(host, key, choices)
        print(one_line(line), file=sys.stderr)
        outcomes.setdefault(outcome, []).append(host.name)
        if outcome == "enroll":
            accepted.setdefault(host.known_hosts, []).append((host.entry, key))
        if outcome == "replace":
            hostkeys.replace(host.known_hosts, host.entry, key)
    for path, entries in accepted.items():
        added = hostkeys.add_all(path, entries)
        print(f"{path}: {added} key(s) added", file=sys.stderr)
    summary = ", ".join(f"{len(names)} {SAID.get(outcome, outcome)}" for outcome, names in outcomes.items())
    print(f"enroll: {summary}", file=sys.stderr)
    if outcomes.get("refused") or outcomes.get("declined"):
        return selection.FAILED
    if outcomes.get("unreachable"):
        return selection.UNREACHABLE
    return selection.OK
