"""Deploy the fleet: the checkout's deploy.py on every host (or --limit's), as pyinfra runs it.

    robotfleet deploy [-i] INVENTORY [SCRIPT] [--limit robot2] [--dry] [--diff] [-y]

The same run, operations and output as `pyinfra inventories/robots.py
deploy.py` (pyinfra's own command line runs in this process, in the
checkout), with robotfleet's INVENTORY (any kind, or -i INVENTORY, as the
other commands take it: no ROBOT_FLEET= needed) and its exit codes, which
tell an unreachable robot from a failed one where pyinfra exits 1 for both.
SCRIPT is deploy.py by default (rollback.py goes back to each robot's
previous release).  Without -y it shows the changes and asks, as pyinfra
does.
Exit status: 0 every host done, 1 a host failed (a step, a host key not
trusted or a login refused), 2 refused before any host was contacted (bad
fleet data, no such inventory or script, a --limit matching nothing), 3 a
host could not be reached (and none failed otherwise).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import robotfleet
from robotfleet import commands, reasons, selection

PYINFRA_ARGV0 = "pyinfra"


def build_parser() -> argparse.ArgumentParser:
    """``robotfleet deploy``'s command line (the shell completion and the manual page read it too)."""
    parser = commands.parser("deploy", __doc__)
    commands.add_inventory(parser)
    parser.add_argument("script", nargs="?", help="the deploy (default: deploy.py; rollback.py goes back)")
    parser.add_argument("--limit", action="append", default=[], help=commands.LIMIT_HELP)
    parser.add_argument("--dry", action="store_true", help="plan only: what would change, change nothing")
    parser.add_argument("--diff", action="store_true", help="show the differences of the files that would change")
    parser.add_argument("-y", "--yes", action="store_true", help="do not ask before applying the changes")
    parser.add_argument("--data", action="append", default=[], help="key=value passed to pyinfra (repeatable)")
    parser.add_argument("--parallel", type=int, metavar="N", help="hosts at once (pyinfra's --parallel)")
    parser.add_argument(
        "--use-sudo-password", action="store_true", help="ask once for the robots' sudo password (never stored)"
    )
    parser.add_argument("-v", dest="verbose", action="count", default=0, help="more of pyinfra's output (-vv, -vvv)")
    return parser


def pyinfra_argv(args, inventory: str, script: str) -> list[str]:
    """pyinfra's command line for ``args`` (pure)."""
    argv = [PYINFRA_ARGV0, *(["-y"] if args.yes else []), *(["-" + "v" * args.verbose] if args.verbose else [])]
    argv += [inventory, script, *[a for limit in args.limit for a in ("--limit", limit)]]
    argv += ["--dry"] * args.dry + ["--diff"] * args.diff + ["--use-sudo-password"] * args.use_sudo_password
    argv += [a for pair in args.data for a in ("--data", pair)]
    argv += ["--parallel", str(args.parallel)] if args.parallel else []
    return argv


def outcome(state) -> int:
    """README's exit code for a pyinfra run that exited 1, from its ``state``
    (None: it stopped before making one): 1 a host failed (an operation, a host key or a login
    refused), else 3 a host could not be reached, else 0."""
    failed = list(state.failed_hosts) if state is not None else []
    if not failed:  # pyinfra failed before any host did (e.g. a deploy file it could not load)
        return selection.FAILED
    for host in failed:
        reason = getattr(host.connector, "unreached", None)
        if host.connected or reason is None or not reasons.unreachable(reason):
            return selection.FAILED
    return selection.UNREACHABLE


def run_pyinfra(argv: list[str], env: dict[str, str]) -> tuple[int, object]:
    """pyinfra's CLI, in this process: (its exit status, its state or None)."""
    from pyinfra.context import ctx_state
    from pyinfra_cli.main import main as pyinfra_main

    saved = sys.argv
    sys.argv = argv
    os.environ.update(env)
    try:
        pyinfra_main()
        code = 0
    except SystemExit as stop:
        code = stop.code if isinstance(stop.code, int) else (0 if stop.code is None else 1)
    finally:
        sys.argv = saved
    return code, (ctx_state.get() if ctx_state.isset() else None)


def main(argv=None) -> int:
    from gevent import monkey

    monkey.patch_all()  # as pyinfra's CLI does first thing (the hosts are greenlets)
    parser = build_parser()
    args = parser.parse_args(argv)
    given = commands.inventory_of(parser, args)
    checkout = Path(robotfleet.CHECKOUT)
    moved = Path.cwd().resolve() != checkout
    script = args.script or ("deploy.py" if not moved else str(checkout / "deploy.py"))
    for path, what in ((given, None), (script, "deploy")):
        if not os.path.exists(path):
            if what is None:
                try:
                    selection.pyinfra_inventory(path)
                except selection.Refused as error:
                    return selection.refused(error)
            print(f"deploy: {path}: no such file (the deploy: deploy.py, rollback.py)", file=sys.stderr)
            return selection.REFUSED
    if moved:  # pyinfra reads config.py and group_data/ from where it runs: the checkout
        given, script = os.path.abspath(given), os.path.abspath(script)
        os.chdir(checkout)
    try:
        inventory, env = selection.pyinfra_inventory(given)
    except selection.Refused as error:
        return selection.refused(error)
    code, state = run_pyinfra(pyinfra_argv(args, inventory, script), env)
    if code != 1:  # done (0), or refused before any host was contacted (2), as it said
        return code
    return outcome(state)
