"""Shell completion of robotfleet's commands, options and their choices, for bash or zsh.

    robotfleet completion bash [--install]
    robotfleet completion zsh [--install]

Prints the script, made by shtab from the commands' own definitions (a
command or option added is in it the next time it is made).  Files and
directories complete where a command takes one (INVENTORY, FILE, DIR).
--install writes it where the shell finds it instead, replacing only one
robotfleet wrote: bash's in bash-completion's directory of the user
($BASH_COMPLETION_USER_DIR/completions, else
$XDG_DATA_HOME or ~/.local/share, then bash-completion/completions/robotfleet),
loaded when robotfleet is first completed in a new shell (without the
bash-completion package, source the file from ~/.bashrc); zsh's as
zsh/site-functions/_robotfleet there, whose directory goes in fpath before
compinit (the line for ~/.zshrc is printed).
Exit status: 0, or 2 (bad arguments, a file there that robotfleet did not write).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import shtab

import robotfleet
from robotfleet import commands, selection

SHELLS = ("bash", "zsh")
MARK = "robotfleet's completion"
# The arguments that complete to file names, by their metavar (DIR: directories).
FILES = ("INVENTORY", "FLEET_FILE", "FILE")


def build_parser() -> argparse.ArgumentParser:
    """``robotfleet completion``'s command line."""
    parser = commands.parser("completion", __doc__)
    parser.add_argument("shell", choices=SHELLS, help="the shell the script is for")
    parser.add_argument("--install", action="store_true", help="write it where the shell finds it, not to stdout")
    return parser


def with_paths(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """``parser``'s tree, each argument that takes a file or a directory
    marked for shtab (``complete``)."""
    for action in parser._actions:  # argparse has no public walk of a parser's arguments
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                with_paths(sub)
            continue
        metavar = action.metavar if isinstance(action.metavar, str) else ""
        if metavar == "DIR":
            action.complete = shtab.DIRECTORY
        elif metavar.startswith(FILES) or action.type is Path or action.dest == "script":
            action.complete = shtab.FILE
    return parser


def script(shell: str) -> str:
    """The completion script for ``shell``, its mark in its first lines (zsh's
    first line is its #compdef)."""
    tree = with_paths(commands.command_tree(commands.summary(__doc__)))
    text = shtab.complete(tree, shell=shell)
    mark = f"# {MARK} for {shell}, from: robotfleet completion {shell} (robotfleet {robotfleet.__version__})\n"
    if text.startswith("#compdef"):
        first, rest = text.split("\n", 1)
        return f"{first}\n{mark}{rest}"
    return mark + text


def installed_at(shell: str) -> Path:
    if shell == "bash":
        user = os.environ.get("BASH_COMPLETION_USER_DIR")
        return Path(user or commands.data_home() / "bash-completion") / "completions" / "robotfleet"
    return commands.data_home() / "zsh" / "site-functions" / "_robotfleet"


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    text = script(args.shell)
    if not args.install:
        sys.stdout.write(text)
        return selection.OK
    path = installed_at(args.shell)
    try:
        commands.install(path, text, MARK)
    except (selection.Refused, OSError) as error:
        reason = error if isinstance(error, selection.Refused) else f"{path}: {error.strerror}"
        return selection.refused(selection.Refused(f"completion: {reason}"))
    if args.shell == "bash":
        print(f"completion: {path}: bash completes robotfleet in new shells (with bash-completion; else: . {path})")
    else:
        print(
            f"completion: {path}: in ~/.zshrc, before compinit: fpath=({path.parent} $fpath); "
            "then zsh completes robotfleet in new shells"
        )
    return selection.OK
