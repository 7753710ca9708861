"""README starts with the operator (issue 18, item 7; issue 28, item 12): the
two commands at the top, then the operator's path in order (install,
describe a fleet, enroll host keys, first deploy, status, updates and
rollouts, push or pull, exit codes) reaching the first deploy command before
line 150, then a list of the docs/ pages that hold the rest, in under 300
lines.  Every command README and docs/ show is checked and run where it
can be (tests/unit/test_doc_commands.py, tests/integration/test_doc_commands.py);
tests/e2e/test_enroll.py runs the path itself on a simulated robot."""

from __future__ import annotations

import re

from robotfleet import selection
from tests import doccommands
from tests.fixtures import ROOT

README = (ROOT / "README.md").read_text()
LINES = README.splitlines()
PATH = [
    "Install for operators",
    "Describing a fleet",
    "Enrolling the robots' host keys",
    "First deploy",
    "Status",
    "Updates and rollbacks",
    "Push or pull",
    "Exit codes",
]


def section(title: str) -> str:
    return README.split(f"\n## {title}\n", 1)[1].split("\n## ", 1)[0]


def test_the_two_commands_stay_at_the_top():
    assert LINES[2:6] == [
        "```sh",
        ".ci/setup && .venv/bin/python -m tests.lab demo    # provision a simulated fleet: "
        "3 robots running real ROS, a laptop",
        ".ci/setup && .venv/bin/python -m tests             # the tests: "
        "unit and integration beside end to end on simulated hosts",
        "```",
    ]


def test_the_operator_path_comes_first_and_reaches_a_deploy_before_line_150():
    titles = re.findall(r"^## (.+)$", README, re.M)
    assert titles == ["What it does", *PATH, "More"], titles
    first_deploy = next(
        c.line
        for c in doccommands.commands(ROOT / "README.md", inline=False)
        if c.program == "pyinfra" and "deploy.py" in c.args
    )
    assert LINES.index("## First deploy") < first_deploy < 150, first_deploy
    assert len(LINES) < 300, len(LINES)


def test_the_path_shows_each_step_s_commands():
    shown: dict[str, list[str]] = {}
    for command in doccommands.commands(ROOT / "README.md", inline=False):
        title = next((line[3:] for line in reversed(LINES[: command.line]) if line.startswith("## ")), None)
        shown.setdefault(title, []).append(command.text)
    assert "robotfleet --version" in shown["Install for operators"]
    assert any(
        c.startswith("robotfleet enroll inventories/robots.py") for c in shown["Enrolling the robots' host keys"]
    )
    assert "pyinfra inventories/robots.py deploy.py" in shown["First deploy"]
    # pyinfra's form for any fleet, next to the first deploy; -i for robotfleet's commands (issue 39, item 1)
    assert any(
        c.startswith("ROBOT_FLEET=") and "pyinfra inventories/robots.py deploy.py" in c for c in shown["First deploy"]
    )
    assert any(c.startswith("robotfleet enroll -i ") for c in shown["Enrolling the robots' host keys"])
    assert "as Ansible's `-i`" in section("First deploy")
    assert any(c.startswith("robotfleet status inventories/robots.py") for c in shown["Status"])
    assert any("--metrics" in c for c in shown["Status"])
    assert any(c.startswith("robotfleet rollout inventories/robots.py") for c in shown["Updates and rollbacks"])
    assert "pyinfra inventories/robots.py rollback.py --limit robot2" in shown["Updates and rollbacks"]
    assert "](docs/guides/pull.md)" in section("Push or pull")


def test_the_rest_is_in_docs_and_more_links_its_index_and_every_kind_of_page():
    """More links docs/README.md, the index of every page
    (tests/unit/test_docs_layout.py), and each guide, reference and explanation."""
    more = section("More")
    assert "](docs/README.md)" in more
    pages = sorted(path.relative_to(ROOT).as_posix() for path in (ROOT / "docs").glob("*/*.md"))
    for page in pages:
        assert f"]({page})" in more, f"README's More does not link {page}"
    for link in re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", README):
        assert (ROOT / link).exists(), link
    for moved in (
        "docs/reference/fleet-file.md",
        "docs/reference/settings.md",
        "docs/guides/host-certificates.md",
        "docs/reference/status.md",
        "docs/guides/laptops.md",
        "docs/guides/releases.md",
        "docs/guides/pull.md",
        "docs/guides/install.md",
    ):
        assert re.search(rf"^(?!- ).*\]\({re.escape(moved)}[)#]", README, re.M), f"the path itself links {moved}"


def test_the_exit_codes_table_is_the_commands_codes():
    """One table for every command (issue 39 item 8): a column a code, a row a command."""
    from robotfleet import cli

    table = section("Exit codes")
    rows = [line for line in table.splitlines() if line.startswith("| ")]
    assert rows[0] == "| command | " + " | ".join(str(code) for code in selection.CODES) + " |", rows[0]
    named = set(re.findall(r"`(?:robotfleet )?([a-z-]+)`", "\n".join(row.split(" | ")[0] for row in rows[1:])))
    assert set(cli.COMMANDS) <= named, set(cli.COMMANDS) - named
    assert rows[1].startswith("| `pyinfra ...` |")
    assert all(row.count(" | ") == len(selection.CODES) for row in rows), rows


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


def test_one_minimum_python_for_the_install_the_build_and_pull_robots():
    import tomllib

    from robotfleet import build_backend
    from robotfleet.fleet import pull_mode

    declared = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["requires-python"]
    assert declared == ">=%d.%d" % build_backend.MINIMUM and build_backend.MINIMUM == pull_mode.MIN_PYTHON
