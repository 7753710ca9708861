"""Halt the current pull release: robots that have not started it do not start.

    robotfleet halt [--reason TEXT] [--remote NAME|URL | --to-dir DIR] [--keys DIR]

A halt is signed like a release: the next version of the release record,
with the same code and images and `halt: true`.  Robots already on the
release keep it (roll them back with a new release, or rollback.py); the
waves that have not opened never will.  Publishing a new release ends the
halt.  See docs/guides/pull.md.
"""

from __future__ import annotations

import argparse

from robotfleet import commands, selection
from robotfleet.pull.operator import commandline, publishing


def build_parser() -> argparse.ArgumentParser:
    """``robotfleet halt``'s command line (the shell completion and the manual page read it too)."""
    parser = commands.parser("halt", __doc__)
    parser.add_argument("--reason", default="halted by the operator", help="one line robots report with the halt")
    commandline.add_channel(parser)
    commandline.add_expiry(parser)
    return parser


def halt(args) -> int:
    if "\n" in args.reason or len(args.reason) > 500:
        raise commandline.Failed("--reason: give one line of at most 500 characters; nothing was halted")
    keys, expiry = commandline.keys_of(args), commandline.expiry_of(args)
    keys.signer("online")
    chosen, repository = commandline.opened(args)
    try:
        halted = publishing.halt(repository, keys, args.reason, expiry, commandline.now())
    except publishing.PublishError as error:
        raise commandline.Failed(str(error)) from None
    where = commandline.pushed(chosen, f"halt: release {halted.version} ({args.reason})")
    print(f"halt: release {halted.version} halts commit {halted.commit[:12]} ({args.reason}); {where}")
    return selection.OK


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return commandline.run("halt", lambda: halt(args))
