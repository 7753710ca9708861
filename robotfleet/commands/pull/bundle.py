"""Make a first-boot bundle for a pull robot: put it on its image, and it converges itself at first boot.

    robotfleet bundle ROBOT --out DIR [--fleet FILE] [--admin ssh://gitolite3@git.example.com --admin-key FILE]
                     [--name-from machine-id|dmi-serial [--name-prefix robot-]]

DIR/rootfs.tar (unpack it onto the image's root) holds the agent's
configuration for ROBOT from the fleet file (default $ROBOT_FLEET, else
inventories/robots.yaml), the release repository's root.json, the current
release's code archive and wheels (from robotfleet publish's copy of the
repository), robot-pull's units and a first-boot unit, and a single-use
enrollment key; DIR/README says how.  With --admin (a gitolite you
administer) the enrollment key is registered there as ROBOT's, allowed what
the robot's own key will be; the hash of its public half is kept in
.robotfleet/enrollments.json (or $ROBOTFLEET_ENROLLMENTS).  After the robot's first report,
`robotfleet pull-enroll` swaps it for the robot's own key.  With
--name-from, the bundle is for an image shared by many robots: ROBOT is
the fleet entry whose settings they start with, each robot names itself
--name-prefix and its machine-id (or board serial: robotfleet/pull/protocol/naming.py),
and the one enrollment key may report as any name the rule can make but a
registered robot's.  See docs/guides/pull.md.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import robotfleet
from robotfleet import commands, deploy_roles, selection
from robotfleet.fleet import pull_mode
from robotfleet.pull.operator import bundle, enrollments, gitolite, install
from robotfleet.pull.operator.repository import Repository, RepositoryError
from robotfleet.pull.protocol import naming
from robotfleet.pull.protocol.robot_data import DataError, host_data


def add_admin(parser) -> None:
    parser.add_argument(
        "--admin", metavar="URL", help="the gitolite server, as its admin (ssh://gitolite3@host[:port])"
    )
    parser.add_argument("--admin-key", metavar="FILE", help="the admin's private key")
    parser.add_argument(
        "--admin-known-hosts",
        metavar="FILE",
        default=os.path.expanduser("~/.ssh/known_hosts"),
        help="the gitolite server's host key (default ~/.ssh/known_hosts)",
    )


def admin_of(args) -> gitolite.Admin | None:
    if not args.admin:
        return None
    if not args.admin_key:
        raise selection.Refused("--admin needs --admin-key")
    return gitolite.Admin(args.admin.rstrip("/"), args.admin_key, args.admin_known_hosts)


def repository_name(remote: str) -> str:
    """The gitolite repository a pull_remote names: ssh://u@h/fleet -> fleet."""
    path = remote.split("://", 1)[-1].split("/", 1)[-1] if "://" in remote else remote.split(":", 1)[-1]
    return path.strip("/").removesuffix(".git")


def make(args) -> int:
    fleet = args.fleet or os.environ.get("ROBOT_FLEET") or "inventories/robots.yaml"
    try:
        data = host_data(args.robot, fleet, deploy_roles.registry())
    except DataError as error:
        raise selection.Refused(str(error)) from None
    platform = pull_mode.value(data, "pull_platform")
    if not pull_mode.pulls(data):
        raise selection.Refused(f"{fleet}: {args.robot} is not a pull robot (pull_enabled: true)")
    clone = install.releases_clone(robotfleet.CHECKOUT)
    repository = Repository(clone)
    try:
        record = repository.record() if repository.exists() else None
        if record is None:
            raise selection.Refused(f"{clone}: no release published yet (robotfleet publish)")
        if args.robot not in record.robots:
            raise selection.Refused(
                f"release {record.version} is not for {args.robot}: publish a release whose fleet "
                "file has it (pull_enabled: true), then make its bundle"
            )
        code = repository.blob(record.code)
        wheels = [(path.rsplit("/", 1)[-1], repository.blob(path)) for path in record.wheels_for(platform)]
        root = install.trust_root(robotfleet.CHECKOUT, pull_mode.value(data, "pull_trust_root"))
        ca = install.remote_ca(robotfleet.CHECKOUT, pull_mode.value(data, "pull_remote_ca"))
    except (RepositoryError, install.InstallError) as error:
        raise selection.Refused(str(error)) from None
    admin = admin_of(args)
    rule = None
    if args.name_from:
        try:
            user = gitolite.shared_user(args.name_from, args.name_prefix)
        except naming.NamingError as error:
            raise selection.Refused(f"--name-from/--name-prefix: {error}") from None
        rule = (args.name_from, args.name_prefix)
    try:
        public = bundle.make(Path(args.out), args.robot, data, record, code, wheels, root, ca, rule)
    except bundle.BundleError as error:
        raise selection.Refused(str(error)) from None
    owner = user if rule else args.robot
    kept = enrollments.kept_file(robotfleet.CHECKOUT)
    bundle.remember(kept, owner, public, record.version)
    like = f"robots named {args.name_prefix}<{args.name_from}> like " if rule else ""
    print(
        f"bundle: {args.out}/rootfs.tar for {like}"
        f"{args.robot}: release {record.version}, {len(wheels)} wheels "
        f"({platform}); enrollment key {bundle.key_sha256(public)[:16]}... kept in {kept}"
    )
    if admin is not None:
        try:
            remote, shards = pull_mode.value(data, "pull_remote"), pull_mode.value(data, "pull_report_shards")
            gitolite.register(admin, repository_name(remote), owner, public, enrollment=not rule, shards=shards)
        except gitolite.GitoliteError as error:
            print(f"bundle: {error}; the enrollment key is not registered yet", file=sys.stderr)
            return selection.FAILED
        print(f"bundle: the enrollment key is registered with {args.admin} as {owner}'s")
    else:
        print(f"bundle: register the enrollment key with your git server as {owner}'s: {public}")
    return selection.OK


def build_parser() -> argparse.ArgumentParser:
    """``robotfleet bundle``'s command line (the shell completion and the manual page read it too)."""
    parser = commands.parser("bundle", __doc__)
    parser.add_argument("robot")
    parser.add_argument("--out", required=True, metavar="DIR", help="a new directory for the bundle")
    parser.add_argument(
        "-i",
        "--fleet",
        metavar="INVENTORY",
        help="the fleet file or an Ansible inventory file or directory (default $ROBOT_FLEET, else "
        "inventories/robots.yaml)",
    )
    add_admin(parser)
    parser.add_argument(
        "--name-from",
        choices=sorted(naming.RULES),
        help="an image shared by many robots: each names itself from its machine-id or board serial",
    )
    parser.add_argument("--name-prefix", default="robot-", help="what the derived names start with (default robot-)")
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return make(args)
    except selection.Refused as error:
        print(f"bundle: {error}", file=sys.stderr)
        return selection.REFUSED
