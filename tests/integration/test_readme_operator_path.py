"""Every command on the README's operator path (tests/unit/test_readme_operator_path.py
finds them) is what the CLI it names takes: its subcommand and options, as
`--help` of the real command prints them, and the files it names."""

from __future__ import annotations

import re
import subprocess
import sys
from functools import lru_cache

from tests.fixtures import PYINFRA, ROOT
from tests.unit.test_readme_operator_path import PATH, commands, section


@lru_cache(maxsize=None)
def help_of(*argv: str) -> str:
    result = subprocess.run([sys.executable, *argv, "--help"], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    return result.stdout


def test_every_command_on_the_path_is_what_the_cli_takes():
    checked = 0
    for title in PATH:
        for argv in commands(section(title)):
            if argv[0] == "robotfleet":
                command = argv[1]
                text = help_of("-m", "robotfleet", command)
                options = [a.split("=")[0] for a in argv[2:] if a.startswith("-")]
            else:
                text = help_of("-c", PYINFRA)
                options = [a for a in argv[1:] if a.startswith("-")]
            for option in options:
                assert re.search(rf"(^|[\s,]){re.escape(option)}\b", text), (title, argv, option)
            for word in argv[1:]:
                if word.endswith(".py") and "/" in word or word in ("deploy.py", "rollback.py"):
                    assert (ROOT / word).exists(), (title, argv, word)
            checked += 1
    assert checked >= 10
