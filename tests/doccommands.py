"""The commands the documentation shows, found as a reader finds them.

Every line of a code block (fenced, or indented four spaces after a blank
line) of README.md, docs/**/*.md and roles/*/README.md that starts with
``robotfleet``, ``pyinfra``, ``python3 -m`` or ``.venv/bin/...`` (after
``VAR=value`` assignments, and in each part of an ``&&`` chain) is a
command; so is an inline code span of prose that starts with ``robotfleet``,
``pyinfra`` or ``python3 -m``.  A ``\\`` at the end of a line continues the
command; ``#`` starts a comment.  A synopsis (``[--json | --format
openmetrics]``) is read with its optional parts in, the first of each set of
alternatives.

A block whose commands are not run by the doc test says why, in an HTML
comment right before it (blank lines between are allowed):

    <!-- illustrative: it provisions the machine it runs on -->
    <!-- illustrative (robotfleet publish, robotfleet halt): they write to the fleet remote -->

the second form covering only the commands starting with those words.
The same commands in what ships beside the docs (the example fleet, the
inventories, files/, the engine's and the roles' docstrings) and the links
there are found by ``shipped_commands`` and ``dangling_links``.
tests/unit/test_doc_commands.py checks what needs no process;
tests/integration/test_doc_commands.py checks each command against the
``--help`` of the program it names and runs the ones ``how_to_run`` knows
how to run without robots.  Pure: nothing here starts a process.
"""

from __future__ import annotations

import re
import shlex
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PROGRAMS = ("robotfleet", "pyinfra", "python3 -m ", "python -m ", ".venv/bin/")
INLINE_PROGRAMS = ("robotfleet", "pyinfra", "python3 -m ")
MARKER = re.compile(r"^<!--\s*illustrative(?:\s*\(([^)]*)\))?\s*:\s*(.*?)\s*-->\s*$")
ASSIGNMENT = re.compile(r"^[A-Z_][A-Z0-9_]*=")


def documents() -> list[Path]:
    """The operator's documentation: README.md, docs/ (guides, reference, explanations), each role's README.md."""
    return [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md")), *sorted((ROOT / "roles").glob("*/README.md"))]


@dataclass
class Block:
    doc: str
    line: int  # 1-based line of its first line
    lines: list[tuple[int, str]]  # (line number, text without the block's indentation)
    marker: str | None = None  # the reason given in an illustrative marker
    covers: tuple[str, ...] = ()  # the marker's command prefixes (none: every command)


@dataclass
class Command:
    doc: str
    line: int
    text: str  # as shown, comment and continuation lines joined
    argv: list[str]  # the program's words, synopsis read (see module doc)
    env: dict[str, str] = field(default_factory=dict)
    inline: bool = False
    marker: str | None = None  # why it is not run, if it is not

    @property
    def where(self) -> str:
        return f"{self.doc}:{self.line}: {self.text}"

    @property
    def program(self) -> str:
        """robotfleet, pyinfra, python -m MODULE, or the program's own name."""
        first = self.argv[0]
        if first in ("python", "python3") and len(self.argv) > 2 and self.argv[1] == "-m":
            return "robotfleet" if self.argv[2] == "robotfleet" else f"python -m {self.argv[2]}"
        return first

    @property
    def args(self) -> list[str]:
        """The words after the program."""
        if self.argv[0] in ("python", "python3") and len(self.argv) > 2 and self.argv[1] == "-m":
            return self.argv[3:]
        return self.argv[1:]

    @property
    def subcommand(self) -> str | None:
        """robotfleet's command (``keys init``: keys), or None."""
        if self.program != "robotfleet" or not self.args or self.args[0].startswith("-"):
            return None
        return self.args[0]


def blocks(doc: Path) -> list[Block]:
    """The code blocks of a Markdown file, each with the marker before it."""
    name = str(doc.relative_to(ROOT))
    lines = doc.read_text().splitlines()
    found: list[Block] = []
    pending: tuple[str, tuple[str, ...]] | None = None
    pending_line = 0
    i = 0
    blank_before = True
    while i < len(lines):
        text = lines[i]
        stripped = text.strip()
        marker = MARKER.match(stripped)
        if marker:
            covers = tuple(c.strip() for c in (marker.group(1) or "").split(",") if c.strip())
            pending = (marker.group(2), covers)
            pending_line = i + 1
            i += 1
            blank_before = True
            continue
        fence = re.match(r"^(\s*)(```+)", text)
        if fence:
            indent, ticks = len(fence.group(1)), fence.group(2)
            body, start = [], i + 1
            i += 1
            while i < len(lines) and not lines[i].strip().startswith(ticks):
                body.append((i + 1, lines[i][indent:] if lines[i][:indent].strip() == "" else lines[i].lstrip()))
                i += 1
            found.append(Block(name, start + 1, body, *(pending or (None, ()))))
            pending = None
            i += 1
            blank_before = False
            continue
        if blank_before and text.startswith("    ") and stripped:
            body, start = [], i
            while i < len(lines) and (lines[i].startswith("    ") or not lines[i].strip()):
                body.append((i + 1, lines[i][4:]))
                i += 1
            while body and not body[-1][1].strip():
                body.pop()
            found.append(Block(name, start + 1, body, *(pending or (None, ()))))
            pending = None
            blank_before = False
            continue
        if stripped:
            if pending is not None:
                found.append(Block(name, pending_line, [], *pending))  # a marker before no block: reported
                pending = None
            blank_before = False
        else:
            blank_before = True
        i += 1
    if pending is not None:
        found.append(Block(name, pending_line, [], *pending))
    return found


def synopsis(text: str) -> str:
    """A synopsis read as one command: ``[a]`` is a, ``[a | b]`` is a."""
    group = re.compile(r"(?<!\S)\[([^\[\]]*)\](?!\S)")
    while True:
        replaced = group.sub(lambda m: m.group(1).split(" | ")[0].strip(), text)
        if replaced == text:
            return text
        text = replaced


def parse(doc: str, line: int, text: str, inline: bool = False, marker: str | None = None) -> list[Command]:
    """The commands on one (joined) line of a block, or one inline span."""
    found = []
    for part in text.split("&&"):
        try:
            words = shlex.split(synopsis(part.strip()), comments=True)
        except ValueError:
            continue  # an unbalanced quote: not a command line
        env = {}
        while words and ASSIGNMENT.match(words[0]):
            key, value = words.pop(0).split("=", 1)
            env[key] = value
        if not words:
            continue
        head = " ".join(words)
        programs = INLINE_PROGRAMS if inline else PROGRAMS
        if not any(head == p.strip() or head.startswith(p if p.endswith((" ", "/")) else p + " ") for p in programs):
            continue
        if words[0].startswith(".venv/bin/"):
            words[0] = words[0].removeprefix(".venv/bin/")
        shown = " ".join(part.strip().split("#", 1)[0].split()) if not inline else text
        found.append(Command(doc, line, shown, words, env, inline, marker))
    return found


def block_commands(block: Block) -> list[Command]:
    found = []
    joined: list[tuple[int, str]] = []
    for number, text in block.lines:
        if joined and joined[-1][1].endswith("\\"):
            joined[-1] = (joined[-1][0], joined[-1][1][:-1] + " " + text.strip())
        else:
            joined.append((number, text.strip()))
    for number, text in joined:
        for command in parse(block.doc, number, text):
            if block.marker is not None and (
                not block.covers
                or any(command.text.startswith(c) or " ".join(command.argv).startswith(c) for c in block.covers)
            ):
                command.marker = block.marker
            found.append(command)
    return found


def inline_commands(doc: Path) -> list[Command]:
    """Commands in inline code spans of the prose (outside code blocks)."""
    name = str(doc.relative_to(ROOT))
    inside = {number for block in blocks(doc) for number, _ in block.lines}
    text = doc.read_text().splitlines()
    found = []
    paragraph: list[tuple[int, str]] = []

    def flush():
        if not paragraph:
            return
        joined = " ".join(t for _, t in paragraph)
        offsets, at = [], 0
        for number, t in paragraph:
            offsets.append((at, number))
            at += len(t) + 1
        for match in re.finditer(r"(?<!`)`([^`]+)`(?!`)", joined):
            number = max(n for start, n in offsets if start <= match.start())
            found.extend(parse(name, number, match.group(1).strip(), inline=True))
        paragraph.clear()

    fenced = False
    for number, line in enumerate(text, 1):
        if line.strip().startswith("```"):
            fenced = not fenced
            flush()
            continue
        if fenced or number in inside or not line.strip():
            flush()
            continue
        paragraph.append((number, line.strip()))
    flush()
    return found


def commands(doc: Path, inline: bool = True) -> list[Command]:
    found = [c for block in blocks(doc) for c in block_commands(block)]
    return found + (inline_commands(doc) if inline else [])


def all_commands(inline: bool = True) -> list[Command]:
    return [c for doc in documents() for c in commands(doc, inline)]


def checkout_paths(command: Command) -> list[str]:
    """The words of a command that name a file or directory of the checkout."""
    paths = []
    for word in command.args:
        if word.startswith(("-", "/", "~", "$")) or "://" in word or "=" in word or word in ("...", "."):
            continue
        if word in ("deploy.py", "rollback.py", "config.py") or (
            "/" in word and re.match(r"^(inventories|roles|docs|files|tests|group_data|robotfleet)/", word)
        ):
            paths.append(word.rstrip("/"))
    return paths


def options(command: Command) -> list[str]:
    """The options a command passes (``--x=y``: ``--x``), without ``--`` and ``-``."""
    return [word.split("=", 1)[0] for word in command.args if word.startswith("-") and word not in ("-", "--")]


# How the doc test runs a command without robots (tests/integration/test_doc_commands.py):
#   help        --help / --version: exit 0, text on stdout
#   generate    robotfleet generate [--check] in a copy of the checkout: exit 0, nothing changed
#   keys-init   robotfleet keys init into a new key directory: exit 0, both keys 0600
#   inventory   robotfleet inventory of the fleet below: exit 0, what it shows on stdout
#   shell       robotfleet completion / man: printed, or --install'ed under the sandbox's home (the manual
#               page into a virtual environment of the sandbox's): exit 0, what it wrote is there
#   unreachable against a fleet of the same host names on 127.0.0.1 ports nothing listens on (through
#               $ROBOT_FLEET, or named directly: made where the command names it, a .yaml or an Ansible
#               directory): the exit code README's "Exit codes" gives an unreachable robot, one line each
UNREACHABLE_CODE = {"pyinfra": 1, "robotfleet": 3}
CONTACTING = ("status", "enroll", "rollout", "deploy")
SHELL = ("completion", "man")


def inventory_of(command: Command) -> str | None:
    """The inventory a robotfleet command names (INVENTORY, or -i INVENTORY), if it names one."""
    args = command.args
    for option in ("-i", "--inventory"):
        if option in args[1:-1]:
            return args[args.index(option) + 1]
    return args[1] if len(args) > 1 and not args[1].startswith("-") else None


def how_to_run(command: Command) -> tuple[str, int] | None:
    """(how, the exit code the docs give) for a command the doc test runs, else None."""
    if command.inline:
        return None
    args = command.args
    if command.program == "robotfleet":
        if args in (["--version"], ["--help"]) or args[-1:] == ["--help"]:
            return "help", 0
        if args in (["generate"], ["generate", "--check"]):
            return "generate", 0
        if args == ["keys", "init"]:
            return "keys-init", 0
        if command.subcommand in SHELL:
            return "shell", 0
        inventory = inventory_of(command) or ""
        if command.subcommand == "inventory" and inventory.startswith(("inventories/", "../")):
            return "inventory", 0
        if command.subcommand in CONTACTING and inventory.startswith(("inventories/", "../")):
            if command.subcommand == "rollout" and not {"-y", "--yes", "--dry"} & set(args):
                return "unreachable", 2  # it would ask, and there is no terminal to ask in
            return "unreachable", UNREACHABLE_CODE["robotfleet"]
    if (
        command.program == "pyinfra"
        and len(args) > 1
        and args[1] in ("deploy.py", "rollback.py")
        or (command.program == "pyinfra" and args[:1] == ["-y"] and args[2:3] in (["deploy.py"], ["rollback.py"]))
    ):
        inventory = args[0] if args[0] != "-y" else args[1]
        if inventory == "inventories/robots.py":
            return "unreachable", UNREACHABLE_CODE["pyinfra"]
    return None


# What ships beside the docs (issue 39, item 4): the example fleet, the
# inventories, group_data/, files/ and the deploy's own files.  The commands
# and links in their comments (and the .py files' docstrings) are checked
# as the docs' are: a command line in a comment (indented past the comment's
# text) or a `code span`; a link is a path of the checkout, a Markdown
# file's #anchor, or a section named as README, "Title".
SECTION = re.compile(
    r"\b(README|ARCHITECTURE|docs/[\w/-]+|roles/\w+/README)(?:\.md)?"
    r"(?:, \"([^\"]+)\"|, ([A-Z][^\",;:()]*\w)|'s \"([^\"]+)\"|\.md#([\w-]+))"
)
PATH = re.compile(r"(?<![\w/.-])((?:tests|roles|robotfleet|docs|inventories|files|group_data)/[\w./-]*[\w/])")


def shipped() -> list[Path]:
    """The example fleet, inventories/, group_data/, files/, the deploy's files, the engine's and roles' .py."""
    found = [
        *(ROOT / "inventories").iterdir(),
        *(ROOT / "group_data").glob("*.py"),
        *(ROOT / "files").rglob("*"),
        ROOT / "deploy.py",
        ROOT / "rollback.py",
        ROOT / "config.py",
        *(ROOT / "robotfleet").rglob("*.py"),
        *(ROOT / "roles").rglob("*.py"),
    ]
    return sorted(p for p in found if p.is_file() and p.name != "known_hosts" and "__pycache__" not in p.parts)


def comment_lines(path: Path) -> list[tuple[int, str, bool]]:
    """(line, text, whether it is a code line) of each line of ``path``'s
    comments: ``#`` comments, a .py file's docstrings, XML's <!-- -->, and
    the whole of a JSON file (the editors' schema: its descriptions)."""
    text = path.read_text()
    lines = text.splitlines()
    if path.suffix == ".json":
        return [(n, line, False) for n, line in enumerate(lines, 1)]
    found = []
    if path.suffix == ".py":
        import ast

        for node in ast.walk(ast.parse(text)):
            if isinstance(
                node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)
            ) and ast.get_docstring(node):
                first = node.body[0].lineno
                for offset, line in enumerate(ast.get_docstring(node).splitlines()):
                    found.append((first + offset, line, line.startswith("    ")))
    inside = False
    for number, line in enumerate(lines, 1):
        stripped = line.strip()
        if path.suffix == ".xml":
            inside = inside or "<!--" in stripped
            if inside:
                found.append((number, stripped.replace("<!--", "").replace("-->", ""), False))
            inside = inside and "-->" not in stripped
        elif stripped.startswith("#") and not stripped.startswith("#!"):
            body = stripped.lstrip("#")[1:]
            found.append((number, body, body.startswith("  ")))
    return sorted(found)


def shipped_commands(path: Path) -> list[Command]:
    name = str(path.relative_to(ROOT))
    found: list[Command] = []
    joined: list[tuple[int, str, bool]] = []
    for number, text, code in comment_lines(path):
        if joined and joined[-1][2] and joined[-1][1].endswith("\\") and joined[-1][0] == number - 1:
            joined[-1] = (number, joined[-1][1][:-1] + " " + text.strip(), True)
        else:
            joined.append((number, text.strip(), code))
    for number, text, code in joined:
        if code:
            found.extend(parse(name, number, text))
        for span in re.findall(r"(?<!`)`([^`]+)`(?!`)", text):
            found.extend(parse(name, number, span.strip(), inline=True))
    return found


def anchor(title: str) -> str:
    """GitHub's anchor of a Markdown heading."""
    return re.sub(r"[^\w\- ]", "", title.strip().lower()).replace(" ", "-")


def dangling_links(path: Path) -> list[str]:
    """The links of ``path``'s comments that lead nowhere: a path not in the
    checkout, a section or an anchor its Markdown file does not have."""
    name = str(path.relative_to(ROOT))
    missing = []
    for number, text, _ in comment_lines(path):
        for found in PATH.findall(text):
            if not re.search(r"[A-Z<*{]", found) and found != "robotfleet/releases" and not (ROOT / found).exists():
                missing.append(f"{name}:{number}: {found} is not in the checkout")
        for doc, *titles in SECTION.findall(text):
            markdown = ROOT / f"{doc}.md"
            headings = re.findall(r"^#+ (.+)$", markdown.read_text(), re.M) if markdown.is_file() else []
            title = next(t for t in titles if t)
            if title not in headings and title not in map(anchor, headings):
                missing.append(f"{name}:{number}: {doc}.md has no section {title!r}")
    return missing
