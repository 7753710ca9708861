"""python3 -m tests.lab up|down|reset|status [--prefix lab] [--robots 3] [--laptops 1] [--arm64-robots 0] [--git-server]

`engine` only makes sure a Docker engine answers (starting dockerd if it may).
"""

from __future__ import annotations

import argparse
import sys

import docker.errors

from . import hosts
from .emulation import ensure_arm64_emulation
from .engine import LabError, client


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python3 -m tests.lab", description="The simulated robot fleet.")
    commands = parser.add_subparsers(dest="command", required=True)
    for name, text in (
        ("up", "start or reuse the lab"),
        ("reset", "down, then up with fresh hosts"),
        ("down", "remove the lab's containers, network and volumes"),
        ("status", "one line per container"),
        ("engine", "make sure a Docker engine answers (start dockerd if needed)"),
        ("emulation", "register qemu-user for arm64 with binfmt_misc (F flag), for the arm64 hosts"),
        ("demo", "up, then provision the lab with pyinfra and say how to look inside"),
    ):
        command = commands.add_parser(name, help=text)
        if name in ("engine", "emulation"):
            continue
        command.add_argument("--prefix", default="lab", help="lab name (default: lab)")
        if name in ("up", "reset"):
            same = "the previous lab's" if name == "reset" else None
            command.add_argument("--robots", type=int, metavar="N", help=f"number of robots (default: {same or 3})")
            command.add_argument("--laptops", type=int, metavar="N", help=f"number of laptops (default: {same or 1})")
            command.add_argument(
                "--arm64-robots", type=int, metavar="N", help=f"emulated arm64 robots pi1..N (default: {same or 0})"
            )
            command.add_argument(
                "--git-server",
                action="store_true",
                default=None,
                help="also the git server pull mode uses (gitolite3; "
                + ("default: the previous lab's)" if name == "reset" else "kept once started)"),
            )
            command.add_argument(
                "--sensor",
                action="append",
                metavar="NAME",
                help="fake sensor on every robot (repeatable; default: the sensors inventories/lab.yaml declares)",
            )
    return parser


def main(argv: list[str]) -> int:
    args = _parser().parse_args(argv)
    try:
        if args.command == "up":
            hosts.up(
                args.prefix,
                3 if args.robots is None else args.robots,
                1 if args.laptops is None else args.laptops,
                args.sensor,
                arm64_robots=args.arm64_robots or 0,
                git_server=bool(args.git_server),
            )
        elif args.command == "reset":
            hosts.reset(args.prefix, args.robots, args.laptops, args.sensor, args.arm64_robots, args.git_server)
        elif args.command == "demo":
            from .demo import demo

            return demo(args.prefix)
        elif args.command == "engine":
            print(f"lab: Docker engine {client().version()['Version']} answers")
        elif args.command == "emulation":
            print(f"lab: arm64 programs run here: {ensure_arm64_emulation()}")
        elif args.command == "down":
            hosts.down(args.prefix)
        else:
            print("\n".join(hosts.status(args.prefix)))
    except LabError as e:
        print(f"lab: error: {e}", file=sys.stderr)
        return 1
    except docker.errors.DockerException as e:
        print(f"lab: error: docker: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
