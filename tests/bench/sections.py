"""Sections of a results file written by another benchmark than the file's
own: RESULTS.md's by tests.bench.pull and tests.bench.stops, PROFILE.md's by
tests.bench.robot_cpu.  Each sits between two markers and is kept when the
file's own benchmark (tests.bench, tests.bench.profile) rewrites its part.
Their data goes beside, in <file>-<name>.json (RESULTS-pull.json)."""

from __future__ import annotations

import json
import re
from pathlib import Path

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "RESULTS.md"


def cell(value) -> str:
    """A table cell of seconds: two decimals, or a dash for none (pure)."""
    return "-" if value is None else f"{value:.2f}"


def begin(name: str) -> str:
    return f"<!-- section {name}: written by python3 -m tests.bench.{name} -->"


def end(name: str) -> str:
    return f"<!-- end of section {name} -->"


SECTION = re.compile(r"<!-- section (?P<name>[\w-]+): .*? -->\n.*?<!-- end of section (?P=name) -->\n?", re.S)


def kept(text: str) -> str:
    """The sections in ``text``, in their order, a blank line between (pure)."""
    return "\n".join(m.group(0).rstrip("\n") + "\n" for m in SECTION.finditer(text))


def without_sections(text: str) -> str:
    return SECTION.sub("", text).rstrip("\n") + "\n"


def replace(text: str, name: str, body: str) -> str:
    """``text`` with section ``name`` set to ``body``: in its place, or
    appended (pure)."""
    block = f"{begin(name)}\n{body.rstrip()}\n{end(name)}\n"
    for match in SECTION.finditer(text):
        if match.group("name") == name:
            return text[: match.start()] + block + text[match.end() :]
    return text.rstrip("\n") + "\n\n" + block


def write(name: str, body: str, data: dict, path: Path = RESULTS) -> None:
    """Set section ``name`` of RESULTS.md and its data file."""
    text = path.read_text() if path.exists() else "# Fleet benchmark results\n"
    path.write_text(replace(text, name, body))
    (path.parent / f"{path.stem}-{name}.json").write_text(json.dumps(data, indent=2) + "\n")


def rewrite_main(text: str, path: Path = RESULTS) -> str:
    """``text`` (tests.bench's own part) followed by the sections the file
    already holds; what is written."""
    old = path.read_text() if path.exists() else ""
    sections = kept(old)
    return without_sections(text) + ("\n" + sections if sections else "")
