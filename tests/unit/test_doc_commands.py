"""Every command the documentation shows (tests/doccommands.py finds them)
is one the test can check, and what needs no process is checked here: the
program and its subcommand exist, the checkout files it names exist, and
each command is either run by tests/integration/test_doc_commands.py or
marked illustrative, with the reason, in the doc itself.  Paths and tests
the prose names exist too, and so do the commands and links in the
comments of what ships (inventories/, group_data/, files/, the .py files)."""

from __future__ import annotations

import re

import pytest

from robotfleet import cli
from tests import doccommands
from tests.doccommands import ROOT, Command

BLOCK_COMMANDS = doccommands.all_commands(inline=False)
ALL_COMMANDS = doccommands.all_commands()
SHIPPED_COMMANDS = [c for path in doccommands.shipped() for c in doccommands.shipped_commands(path)]
# Programs a command may name that are not the checkout's: the test layers, a new venv, pip.
FOREIGN_MODULES = {"python -m pytest", "python -m venv", "pip"}


def ids(commands: list[Command]) -> list[str]:
    return [f"{c.doc}:{c.line}" for c in commands]


def test_the_commands_are_found_in_every_kind_of_block():
    docs = {c.doc for c in BLOCK_COMMANDS}
    assert {
        "README.md",
        "docs/guides/pull.md",
        "docs/guides/releases.md",
        "docs/reference/status.md",
        "docs/reference/fleet-file.md",
    } <= docs, docs
    assert len(BLOCK_COMMANDS) >= 40, len(BLOCK_COMMANDS)
    shown = {c.text for c in BLOCK_COMMANDS}
    assert ".venv/bin/python -m tests.lab demo" in shown  # fenced, in an && chain
    assert "pyinfra inventories/robots.py deploy.py --dry --diff" in shown  # indented, comment cut
    assert "ROBOT_FLEET=inventory pyinfra inventories/robots.py deploy.py" in shown  # an assignment first
    inline = {c.text for c in ALL_COMMANDS if c.inline}
    assert "robotfleet enroll --fingerprints" in inline


def test_a_synopsis_is_read_with_its_options_in_and_the_first_alternative():
    command = doccommands.parse(
        "x.md",
        1,
        "robotfleet status inventories/robots.py [--limit robots] "
        "[--json | --format openmetrics] [--metrics FILE]   # a comment",
    )[0]
    assert command.argv == [
        "robotfleet",
        "status",
        "inventories/robots.py",
        "--limit",
        "robots",
        "--json",
        "--metrics",
        "FILE",
    ]
    assert command.text == (
        "robotfleet status inventories/robots.py [--limit robots] [--json | --format openmetrics] [--metrics FILE]"
    )
    assert doccommands.parse("x.md", 1, "echo robotfleet status") == []
    chained = doccommands.parse("x.md", 1, "ROBOT_FLEET=f.yaml .venv/bin/pyinfra -y inventories/robots.py deploy.py")
    assert [(c.program, c.env, c.args) for c in chained] == [
        ("pyinfra", {"ROBOT_FLEET": "f.yaml"}, ["-y", "inventories/robots.py", "deploy.py"])
    ]


def test_a_marker_covers_the_block_after_it_and_only_the_commands_it_names(tmp_path, monkeypatch):
    monkeypatch.setattr(doccommands, "ROOT", tmp_path)
    doc = tmp_path / "x.md"
    doc.write_text(
        "text\n\n<!-- illustrative (robotfleet publish): needs a remote -->\n\n"
        "    robotfleet keys init\n    robotfleet publish --renew\n\n"
        "    robotfleet status inventories/robots.py\n\n<!-- illustrative: dangling -->\n\nprose\n"
    )
    found = doccommands.commands(doc, inline=False)
    assert [(c.line, c.marker) for c in found] == [(5, None), (6, "needs a remote"), (8, None)]
    assert [(b.line, b.lines, b.marker) for b in doccommands.blocks(doc) if not b.lines] == [(10, [], "dangling")]


@pytest.mark.parametrize("command", BLOCK_COMMANDS, ids=ids(BLOCK_COMMANDS))
def test_each_command_is_run_by_the_doc_test_or_marked_illustrative_with_its_reason(command):
    if command.marker is None:
        assert doccommands.how_to_run(command), (
            f"{command.where}: the doc test cannot run this; teach tests/doccommands.py how_to_run it, or "
            "say why not before its block: <!-- illustrative: why -->"
        )
    else:
        assert len(command.marker.split()) >= 3, f"{command.where}: say why it is not run"
        for named in re.findall(r"tests/[\w/]+\.py", command.marker):
            assert (ROOT / named).is_file(), f"{command.where}: its marker names {named}, which does not exist"


def test_every_marker_stands_before_a_block_and_covers_a_command():
    for doc in doccommands.documents():
        for block in doccommands.blocks(doc):
            if block.marker is None:
                continue
            assert block.lines, f"{block.doc}:{block.line}: an illustrative marker before no code block"
            covered = [c for c in doccommands.block_commands(block) if c.marker is not None]
            assert covered, f"{block.doc}:{block.line}: an illustrative marker before a block it covers no command of"
            for prefix in block.covers:
                assert any(c.text.startswith(prefix) for c in covered), (block.doc, block.line, prefix)


def keys_actions() -> set[str]:
    return set(
        re.findall(r'add_parser\("([\w-]+)"', (ROOT / "robotfleet" / "commands" / "pull" / "keys.py").read_text())
    )


def placeholder(word: str) -> bool:
    """COMMAND, ..., a|b|c: a synopsis's stand-ins (in the engine's docstrings)."""
    return word == "..." or word.isupper()


@pytest.mark.parametrize("command", ALL_COMMANDS + SHIPPED_COMMANDS, ids=ids(ALL_COMMANDS + SHIPPED_COMMANDS))
def test_each_command_names_a_program_and_files_that_exist(command):
    program = command.program
    if program == "robotfleet":
        if command.subcommand and not placeholder(command.subcommand):
            assert command.subcommand in cli.COMMANDS, (
                f"{command.where}: robotfleet has no command {command.subcommand!r}"
            )
        if command.subcommand == "keys" and len(command.args) > 1:
            for action in command.args[1].split("|"):
                assert action in keys_actions(), f"{command.where}: robotfleet keys has no {action!r}"
    elif program.startswith("python -m ") and program not in FOREIGN_MODULES:
        module = program.removeprefix("python -m ")
        source = ROOT / module.replace(".", "/")
        source = source / "__main__.py" if source.is_dir() else source.with_suffix(".py")
        assert source.is_file(), f"{command.where}: no module {module} in the checkout"
        text = source.read_text()
        # an entry point kept at its old name (robotfleet.pull.agent, robotfleet.commands.converge) runs the
        # module it imports main from: its options are that module's
        entry = re.search(r"^\s*from (robotfleet\.[\w.]+) import main$", text, re.M)
        if entry:
            text = (ROOT / (entry[1].replace(".", "/") + ".py")).read_text()
        words = [w for w in command.args if not w.startswith("-")]
        if module == "tests.lab" and words:
            assert f'"{words[0]}"' in text, f"{command.where}: python3 -m tests.lab has no command {words[0]!r}"
        for option in doccommands.options(command):
            assert f'"{option}"' in text, f"{command.where}: {module} takes no {option}"
        if command.args[:1] == ["..."]:
            assert module == "robotfleet", command.where
    else:
        assert program in ("pyinfra", *FOREIGN_MODULES), f"{command.where}: what is {program!r}?"
    for path in doccommands.checkout_paths(command):
        assert (ROOT / path).exists(), f"{command.where}: {path} is not in the checkout"


def test_the_paths_and_tests_the_docs_name_exist():
    """`roles/payload/release.py`, `tests/e2e/test_x.py::test_y` in the prose: a
    renamed file or test makes its sentence false."""
    missing = []
    tests = {p.name: p for p in (ROOT / "tests").glob("*/test_*.py")}
    for doc in doccommands.documents():
        text = doc.read_text()
        for span in re.findall(r"`([^`\n]+)`", text):
            if ": " in span:
                continue  # a setting's example value (`ssh_revoked_host_keys: inventories/revoked.krl`)
            for path in re.findall(
                r"(?<![\w/.-])((?:tests|roles|robotfleet|docs|inventories|files|group_data)/"
                r"[\w./-]*[\w/])",
                span,
            ):
                if path == "robotfleet/releases":  # the releases branch
                    continue
                if not re.search(r"[A-Z<*]", path) and not (ROOT / path).exists():
                    missing.append(f"{doc.relative_to(ROOT)}: {path}")
        current = None
        for path, name in re.findall(r"([\w/]*test_\w+\.py)?::(test_\w+)", text):
            if path:
                current = ROOT / path if "/" in path else tests.get(path)
            if current is None or not current.is_file():
                missing.append(f"{doc.relative_to(ROOT)}: {path}::{name}")
            elif not re.search(rf"^(?:async )?def {name}\(", current.read_text(), re.M):
                missing.append(f"{doc.relative_to(ROOT)}: {current.relative_to(ROOT)}::{name}")
    assert missing == [], "\n".join(missing)


def test_ci_runs_the_readmes_test_command():
    """README's second command is what CI runs (its marker says so)."""
    assert ".ci/setup && .venv/bin/python -m tests\n" in (ROOT / ".ci" / "run").read_text()
    assert ".ci/setup && .venv/bin/python -m tests " in (ROOT / "README.md").read_text()


def test_the_commands_of_shipped_comments_are_found():
    """Comments and docstrings of what ships (the example fleet, the
    inventories, the deploy's files, the engine and the roles): command
    lines, `code spans`, continued lines (issue 39, item 4)."""
    fleet = [c.text for c in SHIPPED_COMMANDS if c.doc == "inventories/robots.yaml"]
    assert fleet[0].startswith("robotfleet enroll inventories/robots.py"), fleet
    assert {c.text for c in SHIPPED_COMMANDS if c.doc == "rollback.py"} >= {
        "pyinfra inventories/robots.py rollback.py --limit robot2",
        "pyinfra inventories/robots.py rollback.py",
    }
    pull = next(c for c in SHIPPED_COMMANDS if c.doc == "inventories/pull.py")
    assert (pull.env["ROBOT_FLEET_HOST"], pull.args) == ("robot1", ["-y", "inventories/pull.py", "deploy.py"])
    assert {c.doc for c in SHIPPED_COMMANDS} >= {
        "inventories/lab.yaml",
        "inventories/local.py",
        "deploy.py",
        "robotfleet/cli.py",
        "robotfleet/commands/status.py",
    }


def test_the_links_of_shipped_comments_lead_somewhere():
    """A path of the checkout, a Markdown file's #anchor, README, "Title":
    each exists (robots.yaml once sent readers to a README section
    "Laptops" that was gone)."""
    missing = [line for path in doccommands.shipped() for line in doccommands.dangling_links(path)]
    assert missing == [], "\n".join(missing)


def test_a_dangling_link_or_command_in_a_comment_is_found(tmp_path, monkeypatch):
    monkeypatch.setattr(doccommands, "ROOT", tmp_path)
    (tmp_path / "README.md").write_text("# x\n\n## Describing a fleet\n")
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "laptops.md").write_text("# A laptop provisioning itself\n")
    (tmp_path / "inventories").mkdir()
    for name in ("robots.py", "local.py"):
        (tmp_path / "inventories" / name).write_text("")
    fleet = tmp_path / "robots.yaml"
    fleet.write_text(
        '# see README, Describing a fleet: fine; (see README, "Laptops"); docs/gone.md\n'
        "# docs/laptops.md#a-laptop-provisioning-itself, docs/laptops.md#nowhere\n"
        "#   python3 -m engine enroll inventories/robots.py\n"
        "# prose: robotfleet reads it, and `pyinfra inventories/local.py deploy.py`\n"
    )
    assert doccommands.dangling_links(fleet) == [
        "robots.yaml:1: docs/gone.md is not in the checkout",
        "robots.yaml:1: README.md has no section 'Laptops'",
        "robots.yaml:2: docs/laptops.md has no section 'nowhere'",
    ]
    assert [(c.line, c.program) for c in doccommands.shipped_commands(fleet)] == [
        (3, "python -m engine"),
        (4, "pyinfra"),
    ]
