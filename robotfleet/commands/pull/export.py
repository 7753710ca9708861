"""Write the current pull release to removable media or a LAN share, with its images, for robots with no network.

    robotfleet export DIR [--remote NAME|URL | --to-dir REPO] [--keys DIR] [--timestamp-expiry 30d]

The release published last (on the fleet remote's robotfleet/releases
branch, or in --to-dir) is re-signed with the online key with one more
kind of TUF target: an archive of each image its robots run, for each
robot's machine (pull_platform), read from the image's registry (no Docker
engine needed here), and media.json naming them.  The re-signed metadata
goes back where the release is (robots on the network see the same
release, and download no archive); DIR gets the whole signed repository:
metadata, code, wheels and the archives.  Copy DIR onto a USB stick or an
NFS share; a robot whose pull_media_dir holds it converges from it with the
same checks as over the network, loads the images (docker load) and checks
each one's id against the signed release before it runs them.

The media are refused once their timestamp expires (--timestamp-expiry,
7 days by default): give the time the media must last.  See docs/guides/pull.md.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from robotfleet import commands, deploy_roles, selection
from robotfleet.pull.operator import commandline
from robotfleet.pull.operator import export as exporting
from robotfleet.pull.operator.keys import ONLINE


def build_parser() -> argparse.ArgumentParser:
    """``robotfleet export``'s command line (the shell completion and the manual page read it too)."""
    parser = commands.parser("export", __doc__)
    parser.add_argument(
        "medium",
        type=Path,
        metavar="DIR",
        help="where the release and its images are written (a mounted USB stick, an NFS share)",
    )
    commandline.add_channel(parser)
    commandline.add_expiry(parser)
    return parser


def export(args) -> int:
    keys, expiry = commandline.keys_of(args), commandline.expiry_of(args)
    online = keys.signer(ONLINE)
    chosen, repository = commandline.opened(args)
    args.medium.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="robotfleet-export-") as work:
        try:
            done = exporting.export(
                repository,
                args.medium,
                args.checkout,
                deploy_roles.roles(),
                deploy_roles.registry(),
                online,
                expiry,
                commandline.now(),
                Path(work),
            )
        except exporting.ExportError as error:
            raise commandline.Failed(str(error)) from None
    where = commandline.pushed(chosen, f"export: release {done.version} with {done.images} image archive(s)")
    print(
        f"export: release {done.version} for {done.robots} robot(s), {done.images} image archive(s) "
        f"({done.size / (1 << 20):.1f} MiB), written to {args.medium}; timestamp valid until "
        f"{repository.timestamp().signed.expires:%Y-%m-%dT%H:%M:%SZ}; metadata {where}"
    )
    return selection.OK


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return commandline.run("export", lambda: export(args))
