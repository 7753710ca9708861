"""robotfleet's manual page (man robotfleet): every command and option, from their own definitions.

    robotfleet man [--install]

Prints the page (roff, for man: `robotfleet man | man -l -`), made from the
commands' own definitions and help texts, as `--help` prints them (a
command or option added is in it the next time it is made).  --install
writes it into the environment robotfleet runs from, as
share/man/man1/robotfleet.1 beside its bin/ (.venv/share/man/...), where
man finds it while that environment is on PATH: `man robotfleet`.  It
replaces only a page robotfleet wrote.
Exit status: 0, or 2 (bad arguments, a file there that robotfleet did not write).
"""

from __future__ import annotations

import argparse
import re
import sys
import textwrap
from pathlib import Path

import robotfleet
from robotfleet import commands, selection

MARK = "robotfleet's manual page"
WIDTH = 78  # the usage lines' width, whatever the terminal that makes the page
DESCRIPTION = (
    "The operator's command of the robot fleet provisioner: it enrolls the robots' host keys, shows the fleet's "
    "status, rolls updates out in waves and runs pull mode's releases.  Each command below takes --help for the "
    "same text.  INVENTORY (or -i INVENTORY) is " + commands.INVENTORY_HELP + "."
)


def build_parser() -> argparse.ArgumentParser:
    """``robotfleet man``'s command line."""
    parser = commands.parser("man", __doc__)
    parser.add_argument("--install", action="store_true", help="write it where man finds it, not to stdout")
    return parser


def escaped(text: str) -> str:
    """Text as roff prints it: backslashes and hyphens as such (options stay
    copyable), `code` in bold, no line read as a request."""
    text = text.replace("\\", "\\e").replace("-", "\\-")
    text = re.sub(r"``([^`]+)``|`([^`]+)`", lambda m: f"\\fB{m[1] or m[2]}\\fR", text)
    return re.sub(r"^([.'])", r"\\&\1", text, flags=re.M)


def paragraphs(doc: str) -> list[str]:
    """A command's docstring after its first paragraph (the summary): prose
    filled by man, indented blocks (usage lines, examples) kept as written."""
    out = []
    for block in doc.strip().split("\n\n")[1:]:
        lines = block.split("\n")
        if all(line.startswith(" ") for line in lines if line.strip()):
            out += [".PP", ".RS 4", ".nf", *map(escaped, textwrap.dedent(block).split("\n")), ".fi", ".RE"]
        else:
            out += [".PP", escaped(" ".join(line.strip() for line in lines))]
    return out


def invocation(action: argparse.Action) -> str:
    metavar = action.metavar or ("{" + ",".join(action.choices) + "}" if action.choices else action.dest.upper())
    shown = f"\\fI{escaped(str(metavar))}\\fR"
    if not action.option_strings:
        return f"[{shown}]" if action.nargs == "?" else shown
    value = "" if action.nargs == 0 else f" [{shown}]" if action.nargs == "?" else f" {shown}"
    return ", ".join(f"\\fB{escaped(option)}\\fR{value}" for option in action.option_strings)


def options(parser: argparse.ArgumentParser) -> list[str]:
    """Each argument of ``parser`` but -h, with its help (%(default)s and %% as argparse expands them)."""
    out = []
    for action in parser._actions:  # argparse has no public walk of a parser's arguments
        if isinstance(action, (argparse._HelpAction, argparse._SubParsersAction)) or action.help == argparse.SUPPRESS:
            continue
        text = (action.help or "") % {**vars(action), "prog": parser.prog}
        out += [".TP", invocation(action), escaped(text)]
    return out


def usage(parser: argparse.ArgumentParser) -> list[str]:
    formatter = argparse.HelpFormatter(parser.prog, width=WIDTH)
    formatter.add_usage(parser.usage, parser._actions, parser._mutually_exclusive_groups, prefix="")
    return [".PP", ".nf", *(escaped(line) for line in formatter.format_help().rstrip().split("\n")), ".fi"]


def section(name: str, parser: argparse.ArgumentParser, doc: str, summary: str) -> list[str]:
    """One command's part of the page: its usage, what it does, its arguments, then its own subcommands'."""
    out = [f".SS {escaped(name)}", escaped(summary), *usage(parser), *paragraphs(doc), *options(parser)]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {choice.dest: choice.help or "" for choice in action._choices_actions}
            for sub, subparser in action.choices.items():
                out += section(f"{name} {sub}", subparser, "", helps.get(sub, ""))
    return out


def page() -> str:
    version = robotfleet.__version__
    lines = [
        f'.\\" {MARK}, from: robotfleet man (robotfleet {version})',
        f'.TH ROBOTFLEET 1 "" "robotfleet {version}" "robotfleet"',
        ".SH NAME",
        "robotfleet \\- provision and update a fleet of ROS robots and operator laptops",
        ".SH SYNOPSIS",
        ".B robotfleet",
        ".I COMMAND",
        ".RI [ OPTIONS ]",
        ".br",
        ".B robotfleet",
        "\\fB\\-\\-help\\fR | \\fB\\-\\-version\\fR",
        ".SH DESCRIPTION",
        escaped(DESCRIPTION),
        ".SH COMMANDS",
    ]
    for name in commands.COMMANDS:
        module = commands.module_of(name)
        doc = module.__doc__ or ""
        lines += [".TP", f"\\fB{escaped(name)}\\fR", escaped(commands.summary(doc))]
    lines += ['.SH "EACH COMMAND"']
    for name in commands.COMMANDS:
        module = commands.module_of(name)
        doc = module.__doc__ or ""
        lines += section(f"robotfleet {name}", module.build_parser(), doc, commands.summary(doc))
    lines += ['.SH "EXIT STATUS"', "The same for every command (each one's own cases: README.md, Exit codes):"]
    for code, meaning in selection.CODES.items():
        lines += [".TP", f"\\fB{code}\\fR", escaped(meaning)]
    lines += [
        ".SH ENVIRONMENT",
        ".TP",
        ".B ROBOT_FLEET",
        escaped("The fleet inventories/robots.py reads (default: inventories/robots.yaml beside it)."),
        ".SH FILES",
        ".TP",
        ".I inventories/robots.yaml",
        "The fleet, in the checkout (the deploy repository).",
        ".TP",
        ".I inventories/known_hosts",
        escaped("The robots' host keys (robotfleet enroll)."),
        '.SH "SEE ALSO"',
        escaped(f"README.md and docs/README.md in the checkout ({robotfleet.CHECKOUT}); pyinfra --help."),
    ]
    return "\n".join(lines) + "\n"


def installed_at() -> Path:
    return Path(sys.prefix) / "share" / "man" / "man1" / "robotfleet.1"


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    text = page()
    if not args.install:
        sys.stdout.write(text)
        return selection.OK
    path = installed_at()
    try:
        commands.install(path, text, MARK)
    except (selection.Refused, OSError) as error:
        reason = error if isinstance(error, selection.Refused) else f"{path}: {error.strerror}"
        return selection.refused(selection.Refused(f"man: {reason}"))
    print(f"man: {path}: man robotfleet shows it while {path.parents[3] / 'bin'} is on PATH (else: man -l {path})")
    return selection.OK
