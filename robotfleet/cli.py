"""robotfleet: the operator's command.

    robotfleet enroll INVENTORY [--limit ...] [--fingerprints FILE] [--yes]
    robotfleet status INVENTORY [--limit ...] [--json]
    robotfleet rollout INVENTORY [deploy.py] [--canary 1 --batch 25% --max-failed 10%] [-y]
    robotfleet generate [--check]
    robotfleet publish [FLEET_FILE] [--commit REV] [--remote NAME | --to-dir DIR]
    robotfleet halt [--reason TEXT]
    robotfleet export DIR [--remote NAME | --to-dir DIR]
    robotfleet keys init|show|rotate|prepare|sign|install|generate
    robotfleet bundle ROBOT --out DIR [--admin URL --admin-key FILE]
    robotfleet pull-enroll INVENTORY [--limit ...] [--admin URL --admin-key FILE] [--ssh]
    robotfleet inventory INVENTORY --graph | --list | --host NAME

INVENTORY (or -i INVENTORY) is the fleet as it is kept: the fleet file
(inventories/robots.yaml), an Ansible inventory file (INI or YAML) or
directory, or inventories/robots.py (which reads $ROBOT_FLEET).
`robotfleet COMMAND --help` explains each.  Deploys are plain pyinfra, run
in the checkout: pyinfra inventories/robots.py deploy.py (another fleet:
ROBOT_FLEET=PATH pyinfra inventories/robots.py deploy.py)
"""

from __future__ import annotations

import importlib
import sys

import robotfleet
from robotfleet import commands

# name -> module under robotfleet/commands/ (imported only when run: each
# brings its own dependencies, e.g. gevent for status and rollout)
COMMANDS = {
    "enroll": "enroll",
    "status": "status",
    "rollout": "rollout",
    "generate": "generate",
    "publish": "publish",
    "halt": "halt",
    "export": "export",
    "keys": "keys",
    "bundle": "bundle",
    "pull-enroll": "pullenroll",
    "inventory": "inventoryview",
}


def usage() -> str:
    lines = [__doc__.strip().split("\n\n")[0], "", "commands:"]
    for name, module in COMMANDS.items():
        doc = importlib.import_module(f"robotfleet.commands.{module}").__doc__ or ""
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
    module = importlib.import_module(f"robotfleet.commands.{COMMANDS[argv[0]]}")
    return module.main(argv[1:])
