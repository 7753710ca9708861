"""Publish a signed release for the pull robots: the deploy code at a commit, the fleet file and every image digest.

    robotfleet publish [FLEET_FILE] [--commit REV] [--remote NAME|URL | --to-dir DIR] [--keys DIR]
                       [--canary 1] [--waves 50%,100%] [--pause SECONDS] [--max-failed 0]
    robotfleet publish --renew [--remote NAME|URL | --to-dir DIR] [--keys DIR]

FLEET_FILE (default inventories/robots.yaml) is read as the commit has it;
its hosts with `pull_enabled: true` are the release's robots.  Every image of
their payload is resolved to its digest in its registry now, the deploy
tree at the commit (default HEAD; a tree with uncommitted changes is
refused unless --leave-out-uncommitted: then they are left out, and named)
is archived, the wheels of the robots' platforms (`pull_platform`) are
fetched with pip (cached), and one release
record binding all of them is signed with the online key (TUF targets,
snapshot, timestamp) and pushed to the fleet remote's robotfleet/releases
branch (or written to --to-dir).  The first publish also makes the
repository's root, signed with the root key.

--renew re-signs the short-lived timestamp (and whatever else is due)
without a new release: run it daily, or robots refuse the repository as
expired once the timestamp's validity (--timestamp-expiry, 7 days) ends.
See docs/guides/pull.md.
"""

from __future__ import annotations

import argparse
import os
import re
import sys
import tempfile
from pathlib import Path

from robotfleet import commands, deploy_roles, selection
from robotfleet.pull.operator import commandline, publishing
from robotfleet.pull.operator.keys import ONLINE, ROOT
from robotfleet.pull.protocol import waves


def default_wheel_cache() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base, "robotfleet", "wheels")


def build_parser() -> argparse.ArgumentParser:
    """``robotfleet publish``'s command line (the shell completion and the manual page read it too)."""
    parser = commands.parser("publish", __doc__)
    parser.add_argument(
        "fleet",
        nargs="?",
        default=publishing.DEFAULT_FLEET,
        metavar="FLEET_FILE",
        help=f"the fleet file, a path in the commit (default {publishing.DEFAULT_FLEET})",
    )
    parser.add_argument("--commit", default="HEAD", metavar="REV", help="the deploy code's commit (default HEAD)")
    parser.add_argument(
        "--leave-out-uncommitted",
        action="store_true",
        help="publish the commit though the working tree has uncommitted changes: they are left out of the "
        "release (a release is a commit), and named",
    )
    # its old name, which read as if the changes were published: still taken, with a note
    parser.add_argument("--allow-dirty", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--renew", action="store_true", help="only re-sign what is due (timestamp); no new release")
    parser.add_argument("--canary", default="1", help="robots of the first wave: a number or a share (default 1)")
    parser.add_argument(
        "--waves",
        default="100%",
        help="cumulative shares of the robots after the canaries, comma-separated (default 100%%)",
    )
    parser.add_argument(
        "--pause",
        type=int,
        default=None,
        help="seconds between waves (default: the robots' longest pull_interval + pull_jitter, so each wave's "
        "robots have checked before the next opens)",
    )
    parser.add_argument(
        "--max-failed",
        default="0",
        help="failures of earlier waves tolerated before a wave starts (number or share; default 0)",
    )
    wheel = parser.add_mutually_exclusive_group()
    wheel.add_argument(
        "--wheel-cache",
        type=Path,
        default=None,
        metavar="DIR",
        help="where pip's downloads are kept (default ~/.cache/robotfleet/wheels)",
    )
    wheel.add_argument(
        "--no-wheels",
        action="store_true",
        help="carry no wheels (robots then install their venv from an index themselves)",
    )
    parser.add_argument(
        "--platform",
        action="append",
        default=[],
        metavar="cpXY-MACHINE",
        help="also carry wheels for this platform (beyond the pull hosts' pull_platform)",
    )
    parser.add_argument("--index-url", help="the Python package index pip downloads wheels from (default PyPI)")
    parser.add_argument(
        "--refresh-wheels",
        action="store_true",
        help="ask the index for newer wheels even when the cache holds every requirement",
    )
    commandline.add_channel(parser)
    commandline.add_expiry(parser)
    return parser


def parse_args(argv: list[str]):
    return build_parser().parse_args(argv)


# The plan's fields as the options that give them, for its problems' lines.
OPTIONS = {"canary": "--canary", "waves": "--waves", "pause": "--pause", "max_failed": "--max-failed"}


def plan_of(args) -> waves.Plan:
    """The rollout plan the options give; ValueError naming the option (``--waves 50%,40%: its share 2: ...``)."""
    try:
        return waves.parse_plan(
            {
                "canary": args.canary,
                "waves": [w.strip() for w in args.waves.split(",")],
                "pause": 0 if args.pause is None else args.pause,
                "max_failed": args.max_failed,
            },
            where="options",
        )
    except ValueError as error:
        found = re.match(r"options\.(\w+)(?:\[(\d+)\])?: ", str(error))
        if not found:
            raise
        option = OPTIONS[found[1]]
        shown = f"{option} {getattr(args, found[1])}" + (f": its share {int(found[2]) + 1}" if found[2] else "")
        raise ValueError(f"{shown}: {str(error)[found.end() :]}; nothing was published") from None


def options_of(args) -> publishing.Options:
    plan = plan_of(args)
    return publishing.Options(
        revision=args.commit,
        fleet=args.fleet,
        plan=plan,
        pause_from_checks=args.pause is None,
        expiry=commandline.expiry_of(args),
        wheel_cache=None if args.no_wheels else (args.wheel_cache or default_wheel_cache()),
        index_url=args.index_url,
        refresh_wheels=args.refresh_wheels,
        leave_out_uncommitted=args.leave_out_uncommitted or args.allow_dirty,
        platforms=tuple(args.platform),
    )


def renew(args) -> int:
    keys, expiry = commandline.keys_of(args), commandline.expiry_of(args)
    online = keys.signer(ONLINE)
    chosen, repository = commandline.opened(args)
    if not repository.exists():
        raise commandline.Failed(f"{chosen.url}: no release repository yet; publish a release first")
    signed = repository.renew(online, expiry, commandline.now())
    where = commandline.pushed(chosen, f"renew: {', '.join(signed)}")
    print(
        f"publish: re-signed {', '.join(signed)}; timestamp valid until "
        f"{repository.timestamp().signed.expires:%Y-%m-%dT%H:%M:%SZ}; {where}"
    )
    return selection.OK


def release(args) -> int:
    options = options_of(args)
    if args.allow_dirty:
        print(
            "publish: note: --allow-dirty is now --leave-out-uncommitted: a release is the commit, never the "
            "working tree's changes",
            file=sys.stderr,
        )
    left_out = publishing.uncommitted(args.checkout, options.revision) if options.leave_out_uncommitted else []
    keys = commandline.keys_of(args)
    keys.signer(ONLINE)  # fail before the slow parts
    chosen, repository = commandline.opened(args)
    if not repository.exists():
        keys.signer(ROOT)
    version = publishing.next_version(repository)
    now = commandline.now()
    with tempfile.TemporaryDirectory(prefix="robotfleet-publish-") as work:
        try:
            record, files = publishing.build(
                args.checkout, options, deploy_roles.roles(), deploy_roles.registry(), version, now, Path(work)
            )
            publishing.publish(repository, record, files, keys, options, now)
        except publishing.PublishError as error:
            raise commandline.Failed(str(error)) from None
    where = commandline.pushed(chosen, f"release {record.version}: {record.commit[:12]}")
    images = len({ref for pins in record.images.values() for ref in pins})
    wheels = ", ".join(f"{p} ({len(f)})" for p, f in sorted(record.wheels.items())) or "none"
    print(
        f"publish: release {record.version} ({record.release}): commit {record.commit[:12]}, "
        f"{len(record.robots)} robot(s), {images} image(s) by digest, wheels {wheels}; {where}"
    )
    for line in waves.describe(list(record.robots), record.version, record.rollout, record.published_at):
        print(f"publish: {line}")
    if left_out:
        shown = ", ".join(left_out[:5]) + (f" and {len(left_out) - 5} more" if len(left_out) > 5 else "")
        print(
            f"publish: left out of release {record.version}, changed and not committed: {shown} "
            f"({len(left_out)} file(s)); robots get commit {record.commit[:12]} as committed",
            file=sys.stderr,
        )
    return selection.OK


def main(argv: list[str] | None = None) -> int:
    args = parse_args(sys.argv[1:] if argv is None else argv)
    return commandline.run("publish", lambda: renew(args) if args.renew else release(args))
