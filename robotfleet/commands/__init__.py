"""The operator commands (``robotfleet COMMAND``), one module each."""

import argparse

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
