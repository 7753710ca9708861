"""The operator commands (``robotfleet COMMAND``), one module each."""

import argparse

# --limit's help, the same for every command that takes it (docs/fleet-file.md#--limit).
LIMIT_HELP = "groups or host globs, comma-separated (&group: also in it, !host: not it); repeatable"


def parser(name: str, doc: str) -> argparse.ArgumentParser:
    """A command's parser: ``robotfleet NAME``, its module's docstring as
    its help (the usage lines and the paragraphs after them, whole)."""
    return argparse.ArgumentParser(prog=f"robotfleet {name}", description=doc,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)


def summary(doc: str) -> str:
    """A docstring's first sentence-paragraph, on one line."""
    return " ".join(doc.strip().split("\n\n", 1)[0].split())
