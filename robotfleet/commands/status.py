"""Fleet status: what each host runs and whether it is healthy.

    robotfleet status inventories/robots.py [--limit robot2] [--json | --format openmetrics] [--metrics FILE]
                                            [--html FILE] [--parallel N]

One row per host, one SSH command per host (a pull robot's row comes from
its last report on the fleet's releases remote instead, --remote, default
the one the fleet names; docs/guides/pull.md): the engine's own part (the
host's architecture, as the snapshot reads it) and each role with a status
part (deploy.py's roles) add their columns, e.g. Docker's version, the current
release, its image, container state and health, the GPU driver.
Unreachable hosts are rows too, never an abort, with the reason in words
(the REACHABLE column, and "error" in --json).  Hosts are asked in parallel,
at most --parallel at once (default 200: a handshake costs the operator a
few ms of its one core, so 200 in flight stay far inside the connect timeout,
and powered-off robots, which hold their place for that timeout, leave room
for the others); a line on stderr tells as each answers, the table follows in
inventory order.
--metrics FILE also writes the fleet's state as OpenMetrics text to FILE
(replaced atomically; for node_exporter's textfile collector), and
--format openmetrics prints it instead of the table (for a Pushgateway):
per host up, drift (not in its declared state), and each role's gauges
(the payload's release, health, last change).
--html FILE also writes the fleet as one self-contained page to FILE (the
rows --json prints, each host's health and releases, the latest rollout's
waves, the pull robots' reports and their age; robotfleet/commands/statuspage.py).
Exit status: 0 every host answered, 1 a host failed (answered with an
error, or its host key or login was refused), 2 refused (no such inventory,
a --limit matching nothing), 3 a host was unreachable (and none failed).
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import re
import sys

from robotfleet import commands, deploy_roles, reasons, selection, status_parts
from robotfleet.checkers import one_line
from robotfleet.commands import metrics, progressline, rollout_plan
from robotfleet.commands.status_collect import PARALLEL, collect
from robotfleet.status_parts import columns


def table(rows: list[dict], shown: list[tuple[str, str]]) -> str:
    """The table as text: a header and one line per row, in ``shown``'s columns (pure)."""
    return "\n".join(line.plain for line in table_lines(rows, shown))


def table_lines(rows: list[dict], shown: list[tuple[str, str]]) -> list:
    """The table's lines as rich Text, each host's name in its state's colour
    (shown only where the output is a terminal that takes colour: Console)."""
    from rich.text import Text

    def cell(value):
        if value is True:
            return "yes"
        if value is False:
            return "no"
        return "-" if value in (None, "") else one_line(str(value))

    pull_shown = any(key == "pull" for key, _ in shown)

    def shown_cell(key, r):
        if key == "rollout" and not pull_shown and not r.get(key):  # a pull robot's rollout: its last report
            return cell(r.get("pull"))
        if key == "reachable" and (r.get(key) is False or (r.get("via") == "report" and r.get("error"))):
            return reachable(r)
        return cell(short(key, r.get(key)))

    def short(key, value):
        # The table shows the first 12 digits of a digest; --json has it whole.
        if key == "image" and isinstance(value, str) and "@sha256:" in value:
            return re.sub(r"@sha256:([0-9a-f]{12})[0-9a-f]{52}", r"@sha256:\1", value)
        return value

    cells = [[shown_cell(key, r) for key, _ in shown] for r in rows]
    widths = [max([len(title)] + [len(c[i]) for c in cells]) for i, (_, title) in enumerate(shown)]
    lines = [Text("  ".join(title.ljust(w) for (_, title), w in zip(shown, widths)).rstrip(), style="bold")]
    for r, line in zip(rows, cells):
        text = Text("  ".join(c.ljust(w) for c, w in zip(line, widths)).rstrip())
        if shown and shown[0][0] == "host":
            text.stylize(COLOURS[status_parts.state_of(r)], 0, len(line[0]))
        lines.append(text)
    return lines


# Each host's state in the summary line, in its order, and its colour on a terminal.
COLOURS = {"healthy": "green", "drifted": "yellow", "failed": "red", "unreachable": "magenta"}


def summary(rows: list[dict]) -> str:
    """``3 healthy, 1 failed, 2 unreachable``: the states with hosts in them (pure)."""
    counts = {state: 0 for state in COLOURS}
    for r in rows:
        counts[status_parts.state_of(r)] += 1
    return ", ".join(f"{n} {state}" for state, n in counts.items() if n) or "no host"


def reachable(row: dict) -> str:
    """An unreachable host's REACHABLE cell: ``no:`` and the reason in a word or two (``no: refused``,
    ``no: timed out``, ``no: host key``); the whole line is in --json's "error" and on stderr.  A pull
    robot's in its own words: ``pull: no report yet``, ``pull: stale report``, ``pull: remote out of
    reach``."""
    error = row.get("error") or ""
    if row.get("via") == "report":  # a pull robot: its report is missing, unreadable or stale, or it is stranded
        word = "stale report" if error.startswith("stale report") else PULL_WORDS.get(row.get("pull"), row.get("pull"))
        return f"pull: {word or 'no report yet'}"
    return f"no: {reasons.short_reason(error) or 'error'}"


PULL_WORDS = {"no report": "no report yet", "unreadable": "unreadable report"}


def hosts_at_once(text: str) -> int:
    """--parallel's value (argparse type): a whole number of hosts, 1 or more."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: a number of hosts, 1 or more")
    return value


def progress(found: dict, count: int, total: int, line=None) -> None:
    """As a host answers: one line on stderr (the operator sees the run
    move), or on a terminal the progress ``line`` (progressline.Line) moves
    and only a host that did not answer gets a line of its own above it."""
    error = found.get("error") or ""
    state = (
        "answered"
        if found["reachable"]
        else f"unreachable: {error}"
        if reasons.unreachable(error)
        else f"failed: {error}"
    )  # a host key or login refused: the host was reached
    if line is None or not line.enabled:
        print(one_line(f"[{found['host']}] {state} ({count}/{total})"), file=sys.stderr, flush=True)
        return
    line.advance(failed=int(state != "answered"), total=total)
    if state != "answered":
        line.say(one_line(f"[{found['host']}] {state}"))


def exit_code(rows: list[dict]) -> int:
    """README's exit codes: 1 if a host failed (answered with an error, or
    refused: a host key not trusted, a login refused), else 3 if a host was
    unreachable, else 0."""
    if any(r.get("error") and (r["reachable"] or not reasons.unreachable(r["error"])) for r in rows):
        return selection.FAILED
    if any(not r["reachable"] for r in rows):
        return selection.UNREACHABLE
    return selection.OK


def build_parser() -> argparse.ArgumentParser:
    """``robotfleet status``'s command line (the shell completion and the manual page read it too)."""
    parser = commands.parser("status", __doc__)
    commands.add_inventory(parser)
    parser.add_argument("--limit", action="append", default=[], help=commands.LIMIT_HELP)
    parser.add_argument("--json", action="store_true", help="machine-readable output (--format json)")
    parser.add_argument(
        "-o",
        "--output",
        "--format",
        dest="format",
        choices=("table", "wide", "json", "openmetrics"),
        default=None,
        help="what to print: the table (default: the columns that fit 100 characters), wide (every column, "
        "as kubectl's -o wide), JSON, or OpenMetrics text",
    )
    parser.add_argument("--metrics", metavar="FILE", help="also write OpenMetrics text to FILE, replaced atomically")
    parser.add_argument(
        "--html",
        metavar="FILE",
        help="also write the fleet as one self-contained HTML page to FILE (replaced atomically)",
    )
    parser.add_argument(
        "--remote",
        metavar="NAME|URL",
        help="the remote pull robots report to (default: git config robotfleet.remote, else "
        "their pull_report_remote or pull_remote)",
    )
    parser.add_argument(
        "--parallel",
        type=hosts_at_once,
        default=PARALLEL,
        metavar="N",
        help=f"hosts asked at once (default {PARALLEL})",
    )
    return parser


def main(argv=None) -> int:
    # Hosts are queried in parallel greenlets over paramiko; patching is the
    # command's business, not its importers' (the unit tests import this module).
    from gevent import monkey

    monkey.patch_all()
    import time

    parser = build_parser()
    args = parser.parse_args(argv)
    args.inventory = commands.inventory_of(parser, args)
    if args.json and args.format not in (None, "json"):
        parser.error(f"--json and -o {args.format}: choose one")
    shown = "json" if args.json else args.format or "table"
    for flag, target in (("--metrics", args.metrics), ("--html", args.html)):
        directory = os.path.dirname(os.path.abspath(target)) if target else None
        if directory and (not os.path.isdir(directory) or not os.access(directory, os.W_OK)):
            print(
                one_line(
                    f"status: {flag} {target}: cannot write in {directory} (no such directory, or "
                    "not writable); no host was contacted"
                ),
                file=sys.stderr,
            )
            return selection.REFUSED
    roles = deploy_roles.roles()
    try:
        # the progress line only with the table (nothing of it with --json or OpenMetrics)
        with progressline.Line("status", enabled=shown in ("table", "wide")) as line:
            answered = functools.partial(progress, line=line)
            rows, rollout = rows_of(args.inventory, args.limit, roles, answered, args.remote, args.parallel)
    except selection.Refused as error:
        return selection.refused(error)
    if args.metrics or shown == "openmetrics":
        text = metrics.render(rows + metrics.reported(args.inventory, [r["host"] for r in rows]), roles, time.time())
        if args.metrics:
            try:
                metrics.write(args.metrics, text)
            except OSError as error:
                print(one_line(f"status: cannot write {args.metrics}: {error.strerror}"), file=sys.stderr)
                return selection.FAILED
    if args.html:
        from robotfleet.commands import statuspage

        try:
            statuspage.write(args.html, rows, rollout, roles, time.time())
        except OSError as error:
            print(one_line(f"status: cannot write {args.html}: {error.strerror}"), file=sys.stderr)
            return selection.FAILED
    if shown == "json":
        print(json.dumps(rows, indent=2, sort_keys=True))
    elif shown == "openmetrics":
        sys.stdout.write(text)
    else:
        from rich.console import Console

        cols = columns(roles, wide=shown == "wide")
        if shown == "wide" and any("pull" in r for r in rows):
            from robotfleet.commands.pull.status import COLUMNS

            cols = cols[:-1] + COLUMNS + cols[-1:]
        # colour only on a terminal, none with NO_COLOR (or TERM=dumb); lines never wrapped
        console = Console(highlight=False, soft_wrap=True)
        for line in table_lines(rows, cols):
            console.print(line)
        if rollout:
            print(one_line(rollout_plan.summary(rollout)))
        console.print(summary_text(rows))
    return exit_code(rows)


def summary_text(rows: list[dict]):
    """summary() with each state's count in its colour (rich Text)."""
    from rich.text import Text

    text = Text()
    for part in summary(rows).split(", "):
        if text:
            text.append(", ")
        text.append(part, style=COLOURS.get(part.split(" ", 1)[-1], ""))
    return text


def rows_of(inventory: str, limits: list[str], roles=None, answered=None, remote=None, parallel=PARALLEL):
    """(every row status --json prints, the latest rollout's state or None):
    the hosts of ``inventory`` matching ``limits``, asked at most ``parallel``
    at once (``answered(row, count, total)`` as each answers), each row with
    its place in the latest rollout.  Raises selection.Refused."""
    roles = deploy_roles.roles() if roles is None else roles
    rows = collect(inventory, limits, roles, answered=answered, remote=remote, parallel=parallel)
    rollout = rollout_plan.latest_state()
    for r in rows:
        r["rollout"] = rollout_plan.host_state(rollout, r["host"])
    return rows, rollout
