"""``robotfleet rollout`` over pull robots: no SSH.  It publishes the
release with the rollout's plan (robotfleet publish: canary, the --batch
waves as cumulative shares, --pause between them, --max-failed), then
follows the robots' reports on the fleet remote as they apply it, wave by
wave on their own (robotfleet/pull/protocol/waves.py).  When more robots fail than
the budget allows, it publishes a signed halt (robotfleet halt): the waves
that have not started never do.

Exit status: 0 every robot applied the release, 1 the budget was spent
(halted) or publishing failed, 2 refused, 3 robots had not reported an
outcome for the release within --timeout.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import robotfleet
from robotfleet import selection
from robotfleet.commands.pull import status as pullstatus
from robotfleet.pull.operator import channel
from robotfleet.pull.operator.repository import Repository
from robotfleet.pull.protocol import reports, waves


def add_options(parser) -> None:
    pull = parser.add_argument_group("pull robots (docs/guides/pull.md)")
    pull.add_argument(
        "--fleet",
        default=None,
        metavar="FILE",
        help="the fleet file the release carries, a path in the commit (default $ROBOT_FLEET, "
        "else inventories/robots.yaml)",
    )
    pull.add_argument(
        "--remote",
        metavar="NAME|URL",
        help="the releases remote (default: git config robotfleet.remote, else the robots' pull_remote)",
    )
    pull.add_argument("--keys", metavar="DIR", help="the release keys (default: robotfleet keys' directory)")
    pull.add_argument(
        "--pause",
        type=int,
        default=None,
        help="seconds between two waves opening (default: robotfleet publish's, the robots' longest "
        "pull_interval + pull_jitter)",
    )
    pull.add_argument(
        "--timeout",
        type=int,
        default=None,
        help="seconds to follow the reports before giving up (default: until an hour after the last wave opens)",
    )
    pull.add_argument("--poll", type=int, default=15, help="seconds between two reads of the reports (default 15)")
    pull.add_argument(
        "--publish-option",
        action="append",
        default=[],
        metavar="OPTION",
        help="passed to robotfleet publish (repeatable), e.g. --publish-option=--no-wheels",
    )


def plan_of(args) -> waves.Plan:
    shares, share = [], args.batch
    if share.percent:
        step = max(share.value, 1)
        shares = [f"{min(100, step * i)}%" for i in range(1, 100 // step + 2) if step * (i - 1) < 100]
    else:
        shares = ["100%"]  # a count per wave has no meaning before the robots rank themselves
    return waves.parse_plan(
        {
            "canary": str(args.canary),
            "waves": list(dict.fromkeys(shares)),
            "pause": 0 if args.pause is None else args.pause,
            "max_failed": str(args.max_failed),
        }
    )


def apart(args, plan: waves.Plan) -> str:
    if args.pause is None:
        return "as far apart as the robots' longest pull_interval + pull_jitter"
    return f"{plan.pause} s apart"


def following(timeout: int | None, record) -> int:
    """Seconds to follow the reports of ``record``: ``timeout``, or by
    default an hour past its last wave's opening (the waves' pause is
    publish's choice when --pause is not given)."""
    if timeout is not None:
        return timeout
    last = len(waves.waves(list(record.robots), record.version, record.rollout)) - 1
    return last * record.rollout.pause + 3600


def publish_argv(args, plan: waves.Plan) -> list[str]:
    found = [
        "--canary",
        str(plan.canary),
        "--waves",
        ",".join(str(w) for w in plan.waves),
        "--max-failed",
        str(plan.max_failed),
    ]
    if args.pause is not None:
        found += ["--pause", str(plan.pause)]
    for option in ("remote", "keys"):
        if getattr(args, option):
            found += [f"--{option}", getattr(args, option)]
    fleet = args.fleet or os.environ.get("ROBOT_FLEET") or "inventories/robots.yaml"
    return [fleet, *found, *args.publish_option]


def outcome(report: dict | None, version: int) -> str | None:
    """done, failed or None (not yet) for ``version`` from a robot's report."""
    if not report or "error" in report:
        return None
    if reports.failed_for(report, version):
        return "failed"
    if (report.get("applied") or {}).get("version", 0) >= version and report["result"] in ("applied", "up-to-date"):
        return "done"
    return None


def main(args, hosts: list[tuple[str, object]], pulled: list[str]) -> int:
    pushed = [name for name, _ in hosts if name not in pulled]
    if pushed:
        print(
            f"rollout: {', '.join(pulled[:5])} converge themselves (pull) and {', '.join(pushed[:5])} do not; "
            "roll them out separately (--limit)",
            file=sys.stderr,
        )
        return selection.REFUSED
    try:
        shards = pullstatus.shards_of(hosts)
    except pullstatus.ReportsUnavailable as error:
        print(f"rollout: {error}", file=sys.stderr)
        return selection.REFUSED
    plan = plan_of(args)
    if args.dry:
        print(
            f"rollout: would publish a release for {len(pulled)} pull robot(s): canary {plan.canary}, waves "
            f"{', '.join(str(w) for w in plan.waves)}, {apart(args, plan)}, at most {plan.max_failed} failed"
        )
        return selection.OK
    from robotfleet.commands.pull import halt as halting
    from robotfleet.commands.pull import publish as publishing
    from robotfleet.pull.operator import releases_remote

    given = args.remote
    try:  # one remote for the publish and a halt, as the fleet the release carries names it
        args.remote = releases_remote.of(robotfleet.CHECKOUT, args.remote, fleet=publish_argv(args, plan)[0])
    except releases_remote.Unnamed as error:
        print(f"rollout: {error}", file=sys.stderr)
        return selection.REFUSED
    if publishing.main(publish_argv(args, plan)) != 0:
        return selection.FAILED
    clone = Path(os.environ.get(channel.CLONE_ENV) or robotfleet.CHECKOUT / ".robotfleet" / "releases")
    record = Repository(clone).record()
    robots = list(record.robots)
    url = pullstatus.remote_of(given, hosts)
    allowed = waves.allowed_failures(plan.max_failed, len(robots))
    print(
        f"rollout: release {record.version} published for {len(robots)} robot(s); following their reports "
        f"on {url} (budget: {allowed} failure(s))",
        file=sys.stderr,
        flush=True,
    )
    said: dict[str, str] = {}
    timeout = following(args.timeout, record)
    deadline = time.monotonic() + timeout
    while True:
        try:
            found = pullstatus.fetch(url, shards=shards)
        except pullstatus.ReportsUnavailable as error:
            print(f"rollout: {error}", file=sys.stderr, flush=True)
            found = {}
        for robot in robots:
            state = outcome(found.get(robot), record.version)
            if state and said.get(robot) != state:
                said[robot] = state
                why = (found[robot].get("reason") or "") if state == "failed" else ""
                print(
                    f"rollout: [{robot}] {state}" + (f": {why}" if why else "") + f" ({len(said)}/{len(robots)})",
                    file=sys.stderr,
                    flush=True,
                )
        failed = [r for r, s in said.items() if s == "failed"]
        if len(failed) > allowed:
            reason = f"rollout: {len(failed)} robot(s) failed release {record.version} (budget {allowed})"
            halt_argv = ["--reason", reason] + [
                a for o in ("remote", "keys") if getattr(args, o) for a in (f"--{o}", getattr(args, o))
            ]
            halting.main(halt_argv)
            print(
                f"{reason}: halted; {len(said) - len(failed)} applied it, {len(robots) - len(said)} never start",
                file=sys.stderr,
            )
            return selection.FAILED
        if len(said) == len(robots):
            print(
                f"rollout: release {record.version}: {len(robots) - len(failed)} robot(s) applied it, "
                f"{len(failed)} failed (budget {allowed})",
                file=sys.stderr,
            )
            return selection.OK if not failed else selection.FAILED
        if time.monotonic() > deadline:
            waiting = [r for r in robots if r not in said]
            print(
                f"rollout: release {record.version}: no outcome within {timeout} s from "
                f"{', '.join(waiting[:10])}" + (" ..." if len(waiting) > 10 else ""),
                file=sys.stderr,
            )
            return selection.UNREACHABLE
        time.sleep(args.poll)
