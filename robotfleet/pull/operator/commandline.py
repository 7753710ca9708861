"""What publish, halt and keys share: where the release repository is
(the releases remote's robotfleet/releases branch, releases_remote.py, or --to-dir), where the
keys are, and how long each role's metadata stays valid."""

from __future__ import annotations

import argparse
import datetime
import sys
from pathlib import Path

import robotfleet
from robotfleet import selection
from robotfleet.pull.operator import channel as channels
from robotfleet.pull.operator import releases_remote
from robotfleet.pull.operator.keys import KeyDir, KeyProblem
from robotfleet.pull.operator.repository import Expiry, Repository, RepositoryError, parse_duration


def add_channel(parser: argparse.ArgumentParser) -> None:
    where = parser.add_mutually_exclusive_group()
    where.add_argument(
        "--remote",
        metavar="NAME|URL",
        help="the releases remote whose robotfleet/releases branch is written (default: git config "
        "robotfleet.remote, else the pull robots' pull_remote; never origin unless named)",
    )
    where.add_argument(
        "--to-dir", metavar="DIR", type=Path, help="write the repository into DIR instead (serve it over static HTTPS)"
    )
    parser.add_argument(
        "--checkout",
        metavar="DIR",
        type=Path,
        default=robotfleet.CHECKOUT,
        help="the deploy repository (default: this checkout)",
    )
    parser.add_argument(
        "--keys",
        metavar="DIR",
        type=Path,
        help="the key directory (default: $ROBOTFLEET_KEYS, else ~/.config/robotfleet/keys)",
    )


def add_expiry(parser: argparse.ArgumentParser) -> None:
    default = Expiry()
    for role in ("timestamp", "snapshot", "targets", "root"):
        days = getattr(default, role).days
        parser.add_argument(
            f"--{role}-expiry",
            metavar="DURATION",
            default=f"{days}d",
            help=f"how long {role} metadata stays valid (default {days}d; 90m, 12h, 7d, 4w)",
        )


def expiry_of(args) -> Expiry:
    return Expiry(
        **{
            role: parse_duration(getattr(args, f"{role}_expiry"), f"--{role}-expiry")
            for role in ("timestamp", "snapshot", "targets", "root")
        }
    )


def channel_of(args, writes: bool = True):
    if args.to_dir:
        return channels.DirChannel(args.to_dir)
    try:
        remote = releases_remote.of(args.checkout, args.remote, fleet=getattr(args, "fleet", None), writes=writes)
    except releases_remote.Unnamed as error:
        raise Failed(str(error)) from None
    return channels.GitChannel(args.checkout, remote)


def keys_of(args) -> KeyDir:
    return KeyDir(args.keys)


def now() -> datetime.datetime:
    return datetime.datetime.now(datetime.timezone.utc).replace(microsecond=0)


class Failed(Exception):
    """One line; the command exits with ``code``."""

    def __init__(self, line: str, code: int = selection.REFUSED):
        super().__init__(line)
        self.code = code


def run(name: str, body) -> int:
    """``body()`` with every expected failure as one line on stderr and its exit code."""
    try:
        return body()
    except Failed as error:
        print(f"{name}: {error}", file=sys.stderr)
        return error.code
    except (ValueError, KeyProblem) as error:  # a bad option value (durations, counts); a key missing or unusable
        print(f"{name}: {error}", file=sys.stderr)
        return selection.REFUSED
    except (RepositoryError, channels.ChannelError) as error:  # the remote or its repository failed or refused
        print(f"{name}: {error}", file=sys.stderr)
        return selection.FAILED


def opened(args, writes: bool = True) -> tuple[object, Repository]:
    """The channel the arguments name, opened: (channel, its repository)."""
    chosen = channel_of(args, writes)
    return chosen, Repository(chosen.open())


def pushed(chosen, message: str) -> str:
    """Push and say where (one line)."""
    commit = chosen.push(message)
    if isinstance(chosen, channels.GitChannel):
        return f"pushed {channels.BRANCH} to {chosen.url} ({commit[:12]})"
    return f"written to {chosen.path}"
