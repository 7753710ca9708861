"""Every command of cli.COMMANDS has its command line as a parser of its own
(build_parser), which the shell completion and the manual page are made
from (tests/integration/test_shell_completion.py tries them in bash, zsh
and man): a new command is in both by itself, or this says what it lacks."""

import pytest

from robotfleet import cli, commands
from robotfleet.commands import manual


@pytest.mark.parametrize("name", list(cli.COMMANDS))
def test_each_command_has_its_own_parser_named_for_it(name):
    module = commands.module_of(name)
    assert hasattr(module, "build_parser"), f"robotfleet/commands/{cli.COMMANDS[name]}.py: no build_parser()"
    assert module.build_parser().prog == f"robotfleet {name}"


def test_the_tree_and_the_page_hold_every_command():
    tree = commands.command_tree("")
    (sub,) = [action for action in tree._actions if action.dest == "command"]
    assert list(sub.choices) == list(cli.COMMANDS)
    page = manual.page()
    for name in cli.COMMANDS:
        assert f".SS robotfleet {manual.escaped(name)}\n" in page, name
