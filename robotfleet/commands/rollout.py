"""Roll the fleet out in waves: canaries first, then batches, and stop when
more robots fail than the budget allows.

    robotfleet rollout inventories/robots.py --canary 1 --batch 25% --max-failed 10% [-y]

Each wave is the normal deploy (`pyinfra -y --json INVENTORY deploy.py
--limit <the wave's robots>`); the next wave starts only when every robot of
this one has reached its target (each role with a rollout part says what:
the payload, every image of the robot's compose project running healthy)
or is counted against the budget.
Robots not reached keep their release.  Robots with `pull_enabled: true` are not
deployed over SSH: the rollout publishes a signed release with these waves
and follows the robots' reports (robotfleet/commands/pull/rollout.py).  The state lives in
.rollout/<key>.json on this machine: rerunning the same command resumes with
the robots not yet on the new release.  See docs/guides/releases.md, "Rollouts in waves".
"""

from __future__ import annotations

import argparse
import json
import os
import secrets
import shlex
import subprocess
import sys
import tempfile

from robotfleet import commands, deploy_roles, reasons, selection
from robotfleet import inventory as fleet_inventory
from robotfleet.checkers import one_line
from robotfleet.commands import progressline, status, status_collect
from robotfleet.commands import rollout_plan as waves
from robotfleet.commands.rollout_judge import judge_wave, missing, not_connected, read_overrides, targets_of
from robotfleet.commands.rolloutreport import relay, robot_line, say, summary, table
from robotfleet.fleet import pull_mode
from robotfleet.role import DEPLOYMENT_ENV

PYINFRA = "import sys; from pyinfra_cli.main import main; sys.argv[0] = 'pyinfra'; main()"


def selected_hosts(inventory_path: str, limits: list[str]) -> list[tuple[str, object]]:
    """(name, host data) of the hosts a rollout targets, in inventory order:
    the robots, or what --limit names (a group or a host name pattern, like
    pyinfra; laptops only when asked for).  Raises selection.Refused."""
    inventory = selection.inventory(inventory_path)
    hosts = selection.select(inventory, inventory_path, limits)
    if not limits:
        hosts = [h for h in hosts if "robots" in h.groups]
    return [(h.name, h.data) for h in hosts]


def read_status(inventory: str, hosts: list[str], parallel: int | None = None, answered=None) -> dict[str, dict]:
    """One status row per host (one SSH command each, at most ``parallel``
    at once: the rollout's --parallel, else status's default; ``answered``
    as status_collect.collect's)."""
    parallel = parallel or status_collect.PARALLEL
    rows = status_collect.collect(inventory, hosts, parallel=parallel, answered=answered) if hosts else []
    return {row["host"]: row for row in rows}


def deploy_wave(
    inventory: str, hosts: list[str], extra: list[str], script: str, deployment: str, fleet_env: dict | None = None
) -> dict | None:
    """Run the normal deploy on ``hosts``, named ``deployment`` (the roles
    record it with their results on each host); pyinfra's JSON results (None
    if it printed none, e.g. every host failed).  What it prints is for the
    operator only: no result is read from it (a host can print anything)."""
    limits = [arg for host in hosts for arg in ("--limit", host)]
    command = [sys.executable, "-c", PYINFRA, "-y", "--json", inventory, script, *limits, *extra]
    env = dict(os.environ, PYINFRA_PROGRESS="off", **(fleet_env or {}), **{DEPLOYMENT_ENV: deployment})
    env[fleet_inventory.TOLD_ENV] = "1"  # the fleet's notes: told by the rollout itself
    with tempfile.TemporaryFile("w+") as out:
        proc = subprocess.Popen(command, stdout=out, stderr=subprocess.PIPE, text=True, env=env)
        for line in proc.stderr:
            relay(line)  # what robots sent is in it: escaped on its way to the terminal
        proc.wait()
        out.seek(0)
        try:
            return json.loads(out.read())["results"]
        except (ValueError, KeyError, TypeError):
            return None


def build_parser() -> argparse.ArgumentParser:
    """``robotfleet rollout``'s command line (the shell completion and the manual page read it too)."""
    parser = commands.parser("rollout", __doc__)
    commands.add_inventory(parser)
    parser.add_argument("script", nargs="?", help="the deploy (default: deploy.py)")
    parser.add_argument(
        "--canary", default="1", help="robots in the first wave when none has rollout_canary (default 1)"
    )
    parser.add_argument("--batch", default="25%", help="robots per later wave, a number or a share (default 25%%)")
    parser.add_argument("--max-failed", default="0", help="failures tolerated, a number or a share (default 0)")
    parser.add_argument("--unreachable-fails", action="store_true", help="unreachable robots count as failures")
    parser.add_argument("--limit", action="append", default=[], help=commands.LIMIT_HELP)
    parser.add_argument("--data", action="append", default=[], help="key=value passed to pyinfra (repeatable)")
    parser.add_argument(
        "--parallel",
        type=status.hosts_at_once,
        help="pyinfra's --parallel for each wave (default: CPUs x 20), and the most hosts its status "
        "reads ask at once (default: status's)",
    )
    parser.add_argument("-y", "--yes", action="store_true", help="do not ask before starting")
    parser.add_argument("--dry", action="store_true", help="show the waves and the changes, change nothing")
    from robotfleet.commands.pull import rollout as pullrollout

    pullrollout.add_options(parser)
    return parser


def parse_args(argv):
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.inventory_option and args.inventory and not args.script:  # rollout -i INVENTORY SCRIPT
        args.inventory, args.script = None, args.inventory
    args.inventory = commands.inventory_of(parser, args)
    args.script = args.script or "deploy.py"
    try:
        args.canary = waves.parse_count(args.canary, "--canary")
        args.batch = waves.parse_count(args.batch, "--batch")
        args.max_failed = waves.parse_count(args.max_failed, "--max-failed")
    except ValueError as error:
        parser.exit(2, f"rollout: {error}\n")
    return args


def relayed(command: list[str], fleet_env: dict | None = None) -> int:
    """Run ``command`` with its output escaped on the way (what robots sent
    is in it): stderr as it comes, stdout after; its exit status."""
    with tempfile.TemporaryFile("w+") as out:
        proc = subprocess.Popen(
            command,
            stdout=out,
            stderr=subprocess.PIPE,
            text=True,
            env=dict(os.environ, **(fleet_env or {}), **{fleet_inventory.TOLD_ENV: "1"}),
        )
        for line in proc.stderr:
            relay(line)
        proc.wait()
        out.seek(0)
        for line in out:
            print(one_line(line.rstrip("\r\n")))
    return proc.returncode


def resume_command(argv: list[str]) -> str:
    return "robotfleet rollout " + " ".join(shlex.quote(a) for a in argv if a not in ("--dry",))


def main(argv=None) -> int:
    from gevent import monkey

    monkey.patch_all()
    argv = sys.argv[1:] if argv is None else argv
    args = parse_args(argv)
    if not os.path.exists(args.script):
        say(f"rollout: {args.script}: no such file")
        return 2
    extra = [arg for pair in args.data for arg in ("--data", pair)]
    extra += ["--parallel", str(args.parallel)] if args.parallel else []
    overrides = read_overrides(args.data)

    try:
        hosts = selected_hosts(args.inventory, args.limit)
        # what pyinfra is given: the waves' deploys, the lock and the state's key (one fleet, however it is named)
        args.pyinfra, args.pyinfra_env = selection.pyinfra_inventory(args.inventory)
    except selection.Refused as error:
        return selection.refused(error)
    if not hosts:
        say(f"rollout: {args.inventory} has no robots; laptops are rolled out only when asked for (--limit laptops)")
        return selection.REFUSED
    pulled = [name for name, data in hosts if pull_mode.pulls(data)]
    if pulled:  # robots that converge themselves: publish and follow their reports (docs/guides/pull.md)
        from robotfleet.commands.pull import rollout as pullrollout

        if args.pyinfra_env and not args.fleet:  # the fleet named as the inventory is the one the release carries
            args.fleet = os.path.relpath(args.inventory)
        return pullrollout.main(args, hosts, pulled)
    roles = deploy_roles.roles()
    names = [name for name, _ in hosts]
    targets = {name: targets_of(roles, data, overrides) for name, data in hosts}
    flagged = [name for name, data in hosts if data.get("rollout_canary")]
    plan = waves.build_waves(names, flagged, args.canary, args.batch)
    key = waves.fleet_key(args.pyinfra, names, targets)
    path = waves.state_path(key)
    if args.dry:
        return roll(args, argv, roles, names, targets, plan, key, path, extra)
    try:
        # One rollout of a fleet at a time, whatever its flags (--limit, --data).
        with waves.held(waves.lock_path(args.pyinfra, fleet_inventory.SOURCES)):
            return roll(args, argv, roles, names, targets, plan, key, path, extra)
    except waves.RolloutBusy as busy:
        say(f"rollout: {busy}")
        return selection.REFUSED


def roll(args, argv, roles, names, targets, plan, key, path, extra) -> int:
    """The rollout itself, from its state (resumed or new) to the report."""
    state = waves.load_state(path) or waves.new_state(
        key, args.inventory, plan, targets, waves.allowed_failures(args.max_failed, len(names))
    )
    state["allowed_failures"] = waves.allowed_failures(args.max_failed, len(names))
    state = waves.start_run(state)

    with progressline.Line("status", unit="robots") as line:  # a large fleet's status takes a while
        rows = read_status(
            args.inventory,
            names,
            args.parallel,
            lambda row, n, total: line.advance(failed=int(not row["reachable"]), total=total),
        )
    unreachable = {h: rows[h].get("error") for h in names if not rows.get(h, {}).get("reachable")}
    already = [h for h in names if missing(roles, rows.get(h, {}), targets[h]) is None]
    state["done"] = sorted(set(state["done"]) | set(already))
    for index, wave in enumerate(state["waves"]):
        todo = [h for h in wave if h not in state["done"]]
        notes = ([f"{len(wave) - len(todo)} already on the new release"] if len(todo) < len(wave) else []) + (
            [f"unreachable now: {', '.join(h for h in todo if h in unreachable)}"]
            if set(todo) & set(unreachable)
            else []
        )
        say(f"wave {index + 1}/{len(state['waves'])}: {', '.join(wave)}" + (f" ({'; '.join(notes)})" if notes else ""))
    say(
        f"failure budget: {state['allowed_failures']} robot(s); unreachable robots "
        + ("count" if args.unreachable_fails else "are skipped")
    )

    if args.dry:
        todo = [h for h in waves.pending(state) if h not in unreachable]
        code = selection.OK
        if todo:
            limits = [a for h in todo for a in ("--limit", h)]
            code = (
                selection.FAILED
                if relayed(
                    [sys.executable, "-c", PYINFRA, "--dry", args.pyinfra, args.script, *limits, *extra],
                    args.pyinfra_env,
                )
                else code
            )
        for host, why in unreachable.items():
            say(f"rollout: [{host}] {'unreachable' if reasons.unreachable(why or '') else 'failed'}: {why}")
        network = [h for h, why in unreachable.items() if reasons.unreachable(why or "")]
        refused = [h for h in unreachable if h not in network]
        if refused:  # a host key or login refused: the robot failed
            say(
                f"rollout: dry run incomplete: {len(refused)} robot(s) refused (host key or login), not planned: "
                f"{', '.join(refused)}"
            )
            code = selection.FAILED
        if network and code == selection.OK:
            say(f"rollout: dry run incomplete: {len(network)} robot(s) unreachable, not planned: {', '.join(network)}")
            code = selection.UNREACHABLE
        return code
    if not args.yes:
        if not sys.stdin.isatty():
            say("rollout: not a terminal; pass -y to start without asking")
            return 2
        if input("Start the rollout? [y/N] ").strip().lower() not in ("y", "yes"):
            return 0

    with progressline.Line("rollout", len(names), unit="robots") as line:
        line.advance(len([h for h in names if h in state["done"]]))
        state = run_waves(args, roles, targets, state, path, extra, rows, line)

    print("\n" + table(rows, state))
    print(summary(state))
    if state["status"] == "complete":
        return selection.OK
    reached = [h for h in state["done"] if h in {x for w in state["waves"] for x in w}]
    print(one_line(f"resume:   {resume_command(argv)}"))
    if reached:
        print(
            one_line(
                f"roll back the robots it reached: {selection.pyinfra_command(args.inventory)} rollback.py "
                + " ".join(f"--limit {h}" for h in reached)
            )
        )
    only_skipped = state["status"] != "stopped" and not state["failed"] and state["skipped"]
    return selection.UNREACHABLE if only_skipped else selection.FAILED


def run_waves(args, roles, targets, state, path, extra, rows, line):
    """Each wave not done yet, deployed and judged, until the budget stops
    them (``rows``: each robot's latest status, updated); the state after.
    ``line``: the progress line (progressline.Line), moved as each wave ends."""
    for index, wave in enumerate(state["waves"]):
        todo = [h for h in wave if h not in state["done"]]
        if not todo:
            state = waves.record_wave(state, index, [], {}, {})
            continue
        say("")
        say(f"--> wave {index + 1}/{len(state['waves'])}: {', '.join(todo)}")
        line.wave(f"wave {index + 1}/{len(state['waves'])}")
        deployment = f"rollout-{state['key'][:12]}-wave{index + 1}-{secrets.token_hex(4)}"
        results = deploy_wave(args.pyinfra, todo, extra, args.script, deployment, args.pyinfra_env)
        # A robot the deploy could not reach is not tried again in this wave
        # (no JSON from pyinfra: nor is one that did not answer the status before).
        lost = not_connected(results) | (
            {h for h in todo if not rows.get(h, {}).get("reachable")} if results is None else set()
        )
        wave_rows = read_status(args.inventory, [h for h in todo if h not in lost], args.parallel)
        wave_rows.update(
            {
                h: {
                    "host": h,
                    "reachable": False,
                    "error": rows.get(h, {}).get("error") or "the deploy could not connect",
                }
                for h in lost
            }
        )
        rows.update(wave_rows)
        done, failed, skipped = judge_wave(todo, results, wave_rows, targets, args.unreachable_fails, roles, deployment)
        state = waves.record_wave(state, index, done, failed, skipped)
        waves.save_state(path, state)
        for host in todo:
            say(robot_line(state, host))
        line.advance(len(todo), failed=len(failed))
        if state["status"] == "stopped":
            break
    waves.save_state(path, state)
    return state
