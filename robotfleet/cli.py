"""robotfleet: the operator's command.

    robotfleet deploy INVENTORY [deploy.py] [--limit ...] [--dry] [--diff] [-y]
    robotfleet enroll INVENTORY [--limit ...] [--fingerprints FILE] [--yes]
    robotfleet status INVENTORY [--limit ...] [-o wide | --json]
    robotfleet rollout INVENTORY [deploy.py] [--canary 1 --batch 25% --max-failed 10%] [-y]
    robotfleet generate [--check]
    robotfleet publish [FLEET_FILE] [--commit REV] [--remote NAME | --to-dir DIR]
    robotfleet halt [--reason TEXT]
    robotfleet export DIR [--remote NAME | --to-dir DIR]
    robotfleet keys init|show|rotate|prepare|sign|install|generate
    robotfleet bundle ROBOT --out DIR [--admin URL --admin-key FILE]
    robotfleet pull-enroll INVENTORY [--limit ...] [--admin URL --admin-key FILE] [--ssh]
    robotfleet inventory INVENTORY --graph | --list | --host NAME
    robotfleet completion bash|zsh [--install]
    robotfleet man [--install]

INVENTORY (or -i INVENTORY) is the fleet as it is kept: the fleet file
(inventories/robots.yaml), an Ansible inventory file (INI or YAML) or
directory, or inventories/robots.py (which reads $ROBOT_FLEET).
`robotfleet COMMAND --help` explains each.  robotfleet deploy is pyinfra's
deploy, run in the checkout, as pyinfra inventories/robots.py deploy.py
(another fleet: ROBOT_FLEET=PATH pyinfra inventories/robots.py deploy.py)
"""

from __future__ import annotations

import sys

import robotfleet
from robotfleet import commands

# The commands, name -> module: robotfleet/commands/__init__.py (the completion and
# the manual page read them there too).
COMMANDS = commands.COMMANDS


def usage() -> str:
    lines = [__doc__.strip().split("\n\n")[0], "", "commands:"]
    for name in COMMANDS:
        doc = commands.module_of(name).__doc__ or ""
        lines.append(f"  {name:10} {commands.summary(doc)}")
    lines += [
        "",
        "options:",
        "  -h, --help  this help",
        "  --version   the version of robotfleet and of pyinfra",
        "",
        __doc__.strip().split("\n\n", 1)[1],
    ]
    return "\n".join(lines)


def version() -> str:
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as installed

    try:
        pyinfra = installed("pyinfra")
    except PackageNotFoundError:
        pyinfra = "not installed"
    return f"robotfleet {robotfleet.__version__} (pyinfra {pyinfra}; checkout {robotfleet.CHECKOUT})"


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ("-h", "--help", "help"):
        print(usage(), file=sys.stdout if argv else sys.stderr)
        return 0 if argv else 2
    if argv[0] == "--version":
        print(version())
        return 0
    if argv[0] not in COMMANDS:
        print(
            f"robotfleet: no command {argv[0]!r} (commands: {', '.join(COMMANDS)}; robotfleet --help)", file=sys.stderr
        )
        return 2
    return commands.module_of(argv[0]).main(argv[1:])
