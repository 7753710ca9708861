"""The operator commands (``robotfleet COMMAND``), one module each: its
``main(argv)`` runs it, its ``build_parser()`` is its command line (read by
``command_tree`` for the shell completion and the manual page)."""

import argparse
import importlib
import os
from pathlib import Path

from robotfleet import atomicfile, selection

# name -> module under robotfleet/commands/ (imported only when run: each
# brings its own dependencies, e.g. gevent for status and rollout)
COMMANDS = {
    "deploy": "deploy",
    "enroll": "enroll",
    "status": "status",
    "rollout": "rollout",
    "generate": "generate",
    "publish": "pull.publish",
    "halt": "pull.halt",
    "export": "pull.export",
    "keys": "pull.keys",
    "bundle": "pull.bundle",
    "pull-enroll": "pull.enroll",
    "inventory": "inventoryview",
    "completion": "completion",
    "man": "manual",
}

# --limit's help, the same for every command that takes it (docs/reference/fleet-file.md#--limit).
LIMIT_HELP = (
    "groups, host globs or Ansible patterns (all, robots[0:2]), comma-separated (&group: also in it, "
    "!host: not it); repeatable"
)


def parser(name: str, doc: str) -> argparse.ArgumentParser:
    """A command's parser: ``robotfleet NAME``, its module's docstring as
    its help (the usage lines and the paragraphs after them, whole)."""
    return argparse.ArgumentParser(
        prog=f"robotfleet {name}", description=doc, formatter_class=argparse.RawDescriptionHelpFormatter
    )


def summary(doc: str) -> str:
    """A docstring's first sentence-paragraph, on one line."""
    return " ".join(doc.strip().split("\n\n", 1)[0].split())


INVENTORY_HELP = (
    "the fleet: its file (inventories/robots.yaml), an Ansible inventory file (YAML, INI) or "
    "directory, or a pyinfra inventory (inventories/robots.py, which reads $ROBOT_FLEET)"
)


def add_inventory(parser: argparse.ArgumentParser) -> None:
    """The inventory argument every command that reads the fleet takes: a
    positional INVENTORY or, as Ansible has it, -i INVENTORY (read by
    inventory_of)."""
    parser.add_argument("inventory", nargs="?", metavar="INVENTORY", help=INVENTORY_HELP)
    parser.add_argument(
        "-i", "--inventory", dest="inventory_option", metavar="INVENTORY", help="the same, as Ansible's -i"
    )


def inventory_of(parser: argparse.ArgumentParser, args: argparse.Namespace) -> str:
    """The inventory the command line names (exit 2 with one line when it
    names none or two); any kind: robotfleet/selection.py pyinfra_inventory."""
    if args.inventory and args.inventory_option:
        parser.error(f"the inventory given twice ({args.inventory} and -i {args.inventory_option}); give one")
    if not (args.inventory or args.inventory_option):
        parser.error(
            "no inventory: give the fleet (inventories/robots.yaml, an Ansible inventory file or "
            "directory) or inventories/robots.py, as INVENTORY or -i INVENTORY"
        )
    return args.inventory or args.inventory_option


def module_of(name: str):
    """The module of command ``name`` (a key of COMMANDS), imported."""
    return importlib.import_module(f"robotfleet.commands.{COMMANDS[name]}")


def command_tree(description: str) -> argparse.ArgumentParser:
    """``robotfleet`` with every command of COMMANDS as a subcommand, each
    its own ``build_parser()`` as it parses: what the completion scripts and
    the manual page are made from, so a new command is in them by itself."""
    top = argparse.ArgumentParser(
        prog="robotfleet", description=description, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    top.add_argument("--version", action="store_true", help="the version of robotfleet and of pyinfra")
    sub = top.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMANDS:
        module = module_of(name)
        own = module.build_parser()
        sub.add_parser(
            name,
            parents=[own],
            add_help=False,
            help=summary(module.__doc__ or ""),
            description=own.description,
            formatter_class=own.formatter_class,
        )
    return top


def install(path: Path, text: str, mark: str) -> None:
    """Write generated ``text`` (holding ``mark`` in its first lines) to
    ``path``, whole, replacing only a file that holds it too: what
    robotfleet wrote before, never a file of someone else's (Refused)."""
    if path.exists():
        with path.open(errors="replace") as old:
            head = "".join(old.readline() for _ in range(3))
        if mark not in head:
            raise selection.Refused(f"{path}: there already, and not written by robotfleet; left as it is")
    atomicfile.write(path, text, mode=0o644, make_parents=True)


def data_home() -> Path:
    """Where a user's own data goes: $XDG_DATA_HOME, else ~/.local/share."""
    return Path(os.environ.get("XDG_DATA_HOME") or Path.home() / ".local" / "share")
