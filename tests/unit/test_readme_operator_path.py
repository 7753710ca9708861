"""README starts with the operator (issue 18, item 7): the two commands at
the top, then the operator's path (install, describe a fleet, enroll host
keys, first deploy, status, update, rollback) reaching the first deploy
within about 250 lines; every command on that path is checked against the
CLI it names (its subcommand, its options, the files it names) in
tests/integration/test_readme_operator_path.py.  The e2e test
tests/e2e/test_enroll.py runs the path itself on a simulated robot."""

from __future__ import annotations

import re
import shlex

from robotfleet import selection
from tests.fixtures import ROOT

README = (ROOT / "README.md").read_text()
PATH = ["Install for operators", "Describing a fleet", "Enrolling the robots' host keys", "First deploy", "Status",
        "Updates and rollbacks", "Exit codes"]


def section(title: str) -> str:
    return README.split(f"\n## {title}\n", 1)[1].split("\n## ", 1)[0]


def commands(text: str) -> list[list[str]]:
    found = []
    for line in text.splitlines():
        line = line.strip().split("  #", 1)[0].strip()
        if line.startswith(("robotfleet ", "pyinfra ", ".venv/bin/pyinfra ")):
            found.append(shlex.split(line.replace("[", "").replace("]", "")))
    return found


def test_the_two_commands_stay_at_the_top():
    assert README.splitlines()[2:6] == [
        "```sh",
        ".ci/setup && .venv/bin/python -m tests.lab demo    # provision a simulated fleet: 3 robots and a laptop",
        ".ci/setup && .venv/bin/python -m pytest            # the tests: unit, then end to end on simulated hosts",
        "```",
    ]


def test_the_operator_path_comes_first_and_reaches_a_deploy_within_250_lines():
    titles = re.findall(r"^## (.+)$", README, re.M)
    assert titles[1:1 + len(PATH)] == PATH, titles
    first_deploy = README.splitlines().index("## First deploy")
    assert first_deploy < 250, first_deploy
    assert len(README.splitlines()) < 400
    for moved in ("docs/faults.md", "docs/benchmarks.md", "docs/lab.md", "docs/gpu.md", "docs/security.md",
                  "docs/settings.md", "docs/releases.md", "docs/fleet-file.md"):
        assert f"]({moved})" in README and (ROOT / moved).exists(), moved


def test_the_exit_codes_table_is_the_commands_codes():
    table = section("Exit codes")
    for code in selection.CODES:
        assert f"\n| {code} |" in table, code


def test_the_example_fleet_names_commands_that_work():
    """robots.yaml's comments: no `pyinfra @local deploy.py` (it ignores the
    fleet data and fails); each command's files exist."""
    text = (ROOT / "inventories" / "robots.yaml").read_text()
    comments = "\n".join(line for line in text.splitlines() if line.lstrip().startswith("#"))
    assert "@local" not in comments
    named = re.findall(r"`?((?:pyinfra|robotfleet) [^`\n]+)`?", comments)
    assert named
    for command in named:
        for word in command.split():
            if word.endswith(".py"):
                assert (ROOT / word).exists(), command
