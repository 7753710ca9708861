"""Docs a reader can walk (issue 37, item 8): docs/ is guides (task first),
reference (settings, commands, formats) and explanations (how and why),
each page listed by docs/README.md; every role describes itself in
roles/<role>/README.md with the same sections, docs/reference/roles.md
their index; no page runs a screen without a heading; and every link of
the docs leads to a file and a heading that exist."""

from __future__ import annotations

import re
import sys
from pathlib import Path

from tests import doccommands
from tests.fixtures import ROOT

DOCS = ROOT / "docs"
KINDS = ("guides", "reference", "explanations")
SCREEN = 50  # lines a page may run without a heading
ROLE_SECTIONS = ["Settings", "What a run does"]  # every role's README.md begins with these, in this order
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")


def pages() -> list[Path]:
    return sorted(DOCS.rglob("*.md"))


def linked_docs() -> list[Path]:
    """What a reader opens: README, ARCHITECTURE, docs/, the roles' READMEs, the lab's."""
    return [
        ROOT / "README.md",
        ROOT / "ARCHITECTURE.md",
        *pages(),
        *sorted((ROOT / "roles").glob("*/README.md")),
        ROOT / "tests" / "lab" / "README.md",
    ]


def prose(path: Path) -> list[tuple[int, str]]:
    """(line, text) of a Markdown file outside its fenced code blocks."""
    found, fenced = [], False
    for number, line in enumerate(path.read_text().splitlines(), 1):
        if line.strip().startswith("```"):
            fenced = not fenced
            continue
        if not fenced:
            found.append((number, line))
    return found


def headings(path: Path) -> list[tuple[int, str]]:
    return [(n, line.lstrip("#").strip()) for n, line in prose(path) if re.match(r"^#{1,6} ", line)]


def anchors(path: Path) -> set[str]:
    return {doccommands.anchor(title) for _, title in headings(path)}


def roles() -> list[str]:
    return sorted(p.parent.name for p in (ROOT / "roles").glob("*/settings.py"))


def test_every_page_of_docs_is_a_guide_a_reference_or_an_explanation_and_the_index_lists_it():
    index = (DOCS / "README.md").read_text()
    for page in pages():
        relative = page.relative_to(DOCS).as_posix()
        if relative == "README.md":
            continue
        assert relative.split("/")[0] in KINDS, f"docs/{relative}: not under {', '.join(KINDS)}"
        assert f"]({relative})" in index, f"docs/README.md does not list {relative}"
    for role in roles():
        assert f"](../roles/{role}/README.md)" in index, f"docs/README.md does not list roles/{role}/README.md"
    assert "](docs/README.md)" in (ROOT / "README.md").read_text()


def test_the_commands_reference_names_every_command():
    from robotfleet import cli

    page = (DOCS / "reference" / "commands.md").read_text()
    named = set(re.findall(r"^\| `robotfleet ([a-z-]+)` \|", page, re.M))
    assert named == set(cli.COMMANDS), set(cli.COMMANDS) ^ named


def test_every_role_describes_itself_in_its_folder_with_the_same_sections():
    index = (DOCS / "reference" / "roles.md").read_text()
    for role in roles():
        readme = ROOT / "roles" / role / "README.md"
        assert readme.is_file(), f"roles/{role}/README.md is missing"
        titles = [title for _, title in headings(readme)]
        assert titles[0].endswith(f"(roles/{role})"), f"roles/{role}/README.md: its title names roles/{role}"
        assert titles[1 : 1 + len(ROLE_SECTIONS)] == ROLE_SECTIONS, (
            f"roles/{role}/README.md: its sections begin {titles[1:3]}, not {ROLE_SECTIONS}"
        )
        assert f"](../../roles/{role}/README.md)" in index, f"docs/reference/roles.md does not link roles/{role}"


def long_stretches(paths: list[Path]) -> list[str]:
    """Where a page runs more than a screen without a heading."""
    long = []
    for path in paths:
        lines = path.read_text().splitlines()
        starts = [n for n, _ in headings(path)] + [len(lines) + 1]
        if starts[0] != 1:
            long.append(f"{path.relative_to(ROOT)}:1: the first line is not a heading")
        for start, end in zip(starts, starts[1:]):
            if end - start > SCREEN:
                long.append(f"{path.relative_to(ROOT)}:{start}: {end - start} lines without a heading")
    return long


def broken_links(paths: list[Path]) -> list[str]:
    """The relative links that lead to no file, or to no heading of a Markdown file."""
    broken = []
    for path in paths:
        for number, line in prose(path):
            for target in LINK.findall(re.sub(r"`[^`]*`", "", line)):
                if re.match(r"^[a-z]+:", target):
                    continue  # https:, mailto:
                file, _, anchor = target.partition("#")
                linked = (path.parent / file).resolve() if file else path
                where = f"{path.relative_to(ROOT)}:{number}: {target}"
                if not linked.exists():
                    broken.append(f"{where}: no such file")
                elif anchor and linked.suffix == ".md" and anchor not in anchors(linked):
                    broken.append(f"{where}: {linked.relative_to(ROOT)} has no heading #{anchor}")
    return broken


def test_no_page_runs_a_screen_without_a_heading():
    long = long_stretches([path for path in linked_docs() if path.parent.name != "lab"])  # the lab's: its internals
    assert long == [], "\n".join(long)


def test_every_link_of_the_docs_leads_to_a_file_and_a_heading():
    broken = broken_links(linked_docs())
    assert broken == [], "\n".join(broken)


def test_a_broken_link_and_a_long_page_are_found(tmp_path, monkeypatch):
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    page = tmp_path / "page.md"
    page.write_text(
        "# Title\n\n[there](other.md#gone) [here](#title) [web](https://example.com) `[no](x.md)`\n"
        "[gone](gone.md)\n```\n[in code](nowhere.md)\n# not a heading\n```\n" + "text\n" * SCREEN + "## Next\n"
    )
    (tmp_path / "other.md").write_text("# Other\n")
    assert broken_links([page]) == [
        "page.md:3: other.md#gone: other.md has no heading #gone",
        "page.md:4: gone.md: no such file",
    ]
    assert long_stretches([page]) == [f"page.md:1: {SCREEN + 8} lines without a heading"]
    (tmp_path / "other.md").write_text("text\n# Other\n")
    assert long_stretches([tmp_path / "other.md"]) == ["other.md:1: the first line is not a heading"]


def test_the_pull_protocol_reference_lists_every_refusal_reason_in_order():
    """Its table's reasons are refusals.REASONS, the machine-readable refusal
    of a report: a reason added or renamed in one place fails here."""
    from robotfleet.pull.robot import refusals

    page = DOCS / "reference" / "pull-protocol.md"
    rows = [line for _, line in prose(page) if re.match(r"^\| `[a-z-]+` \|", line)]
    assert [row.split("`")[1] for row in rows] == list(refusals.REASONS), page
