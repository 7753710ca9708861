"""Every command README.md, docs/**/*.md and roles/*/README.md show
(tests/doccommands.py finds them) is what the program it names takes: its
subcommand and options as the real `--help` prints them.  And each one the
doc test can run without robots runs, as written, in a copy of the checkout:
`--help` and `--version`, `robotfleet generate`, `robotfleet keys init`
into a new key directory, and every command that contacts hosts against a
fleet of the host names the docs use, all on 127.0.0.1 ports nothing
listens on (never the example fleet's addresses), where it must exit with
the code README's "Exit codes" gives an unreachable robot and say so per
host.  A block the test cannot run says why in the doc
(tests/unit/test_doc_commands.py checks that every other one is run here)."""

from __future__ import annotations

import re
import shutil
import site
import socket
import subprocess
import sys
import venv
from functools import lru_cache
from pathlib import Path

import pytest

from robotfleet.fleet import yaml12
from tests import doccommands
from tests.fixtures import PYINFRA, ROOT, pyinfra_argv

COMMANDS = doccommands.all_commands()
NOT_COPIED = shutil.ignore_patterns(
    ".git", ".lab", ".venv", "__pycache__", "*.egg-info", "build", ".pytest_cache", ".rollout", ".robotfleet"
)
GENERATED = ("docs/reference/settings.md", "inventories/fleet.schema.json")
# The host names the docs' commands that run name (--limit, --replace), robots and a
# laptop; few robots, so that a rollout's waves are few.
ROBOTS = ["robot1", "robot2"]
NESTED = {"gpus": ["gpu-robot"]}  # a child group of robots
LAPTOPS = {"alice-laptop": {"docker_users": ["alice"], "x11_user": "alice"}}


@lru_cache(maxsize=None)
def help_of(*argv: str) -> str:
    result = subprocess.run(
        [sys.executable, *argv, "--help"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
        stdin=subprocess.DEVNULL,
    )
    assert result.returncode == 0, (argv, result.stderr)
    return result.stdout


def help_for(command: doccommands.Command) -> str:
    if command.program == "pyinfra":
        return help_of("-c", PYINFRA)
    if not command.subcommand:
        return help_of("-m", "robotfleet")
    if command.subcommand == "keys" and len(command.args) > 1 and not command.args[1].startswith("-"):
        return help_of("-m", "robotfleet", "keys", command.args[1])
    return help_of("-m", "robotfleet", command.subcommand)


def synopsis_only(command: doccommands.Command) -> bool:
    """robotfleet COMMAND --help, keys init|show|...: no one program's help to read."""
    words = command.args[:2] if command.subcommand == "keys" else command.args[:1]
    return any(word == "..." or word.isupper() or "|" in word for word in words)


SHIPPED = [c for path in doccommands.shipped() for c in doccommands.shipped_commands(path)]
CHECKED = [c for c in COMMANDS + SHIPPED if c.program in ("robotfleet", "pyinfra") and not synopsis_only(c)]


@pytest.mark.parametrize("command", CHECKED, ids=[f"{c.doc}:{c.line}" for c in CHECKED])
def test_every_command_shown_is_what_the_cli_takes(command):
    text = help_for(command)
    for option in doccommands.options(command):
        assert re.search(rf"(^|[\s,\[]){re.escape(option)}\b", text), f"{command.where}: {option} is not in its --help"


def closed_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


class Sandbox:
    """A copy of the checkout, and a fleet nothing of which answers."""

    def __init__(self, base: Path):
        self.base = base
        self.checkout = base / "robot-fleet"
        shutil.copytree(ROOT, self.checkout, ignore=NOT_COPIED)
        self.port = closed_port()
        (base / "known_hosts").write_text("")
        (base / "home").mkdir()
        self.settings = {
            "payload_image": "registry.example.com/acme/ros-payload:1.4.2",
            "ssh_user": "ops",
            "ssh_port": self.port,
            "ssh_known_hosts_file": str(base / "known_hosts"),
            "ssh_connect_timeout": 2,
            "ssh_connect_retries": 0,
        }
        self.fleet = self.yaml_fleet(base / "fleet.yaml")
        self.yaml_fleet(self.checkout / "inventories" / "robots.yaml")  # named directly: never the example's hosts
        self.runs = 0

    def yaml_fleet(self, path: Path) -> Path:
        local = {"address": "127.0.0.1"}
        path.write_text(
            yaml12.dump(
                {
                    "all": {"vars": self.settings},
                    "robots": {
                        "hosts": {name: local for name in ROBOTS},
                        "children": {
                            group: {"hosts": {name: local for name in names}} for group, names in NESTED.items()
                        },
                    },
                    "laptops": {"hosts": {name: {**local, **data} for name, data in LAPTOPS.items()}},
                }
            )
        )
        return path

    def ansible_directory(self, path: Path) -> Path:
        """The same fleet as an Ansible inventory directory: INI hosts, group_vars/."""
        (path / "group_vars").mkdir(parents=True)
        lines = ["[robots]", *ROBOTS, "", "[robots:children]", *NESTED]
        for group, names in NESTED.items():
            lines += ["", f"[{group}]", *names]
        lines += ["", "[laptops]", *LAPTOPS]
        (path / "hosts").write_text("\n".join(lines) + "\n")
        (path / "group_vars" / "all.yml").write_text(yaml12.dump({"ansible_host": "127.0.0.1", **self.settings}))
        (path / "group_vars" / "laptops.yml").write_text(yaml12.dump(next(iter(LAPTOPS.values()))))
        return path

    def env(self, command: doccommands.Command) -> dict[str, str]:
        self.runs += 1
        env = {
            "PATH": f"{Path(sys.executable).parent}:/usr/bin:/bin",
            "HOME": str(self.base / "home"),
            "ROBOT_FLEET": str(self.fleet),
            "ROBOTFLEET_KEYS": str(self.base / f"keys{self.runs}"),
            "ROBOT_ROLLOUT_DIR": str(self.base / "rollouts"),
            "PYINFRA_PROGRESS": "off",
            "ROBOTFLEET_RELEASES_CLONE": str(self.base / "releases"),
        }
        for key, value in command.env.items():
            if key == "ROBOT_FLEET":
                self.made(self.checkout / value)
            env[key] = value
        return env

    def made(self, path: Path) -> Path:
        """The fleet at ``path``, made if it is not there: YAML for a .yaml
        name, an Ansible inventory directory otherwise."""
        if not path.exists():
            self.yaml_fleet(path) if path.suffix in (".yaml", ".yml") else self.ansible_directory(path)
        return path

    def argv(self, command: doccommands.Command) -> list[str]:
        """The command as written, with absolute paths and FILE placeholders
        under the sandbox, and the files its options read made."""
        if command.program == "robotfleet" and command.subcommand in (*doccommands.CONTACTING, "inventory"):
            inventory = doccommands.inventory_of(command)
            if inventory and not inventory.endswith(".py"):
                self.made(self.checkout / inventory)
        args = []
        for i, word in enumerate(command.args):
            if word.startswith("/") and not word.startswith("/dev/"):
                word = str(self.base / "root" / word.lstrip("/"))
                Path(word).parent.mkdir(parents=True, exist_ok=True)
            elif word in ("FILE", "DIR"):
                word = str(self.base / "placeholders" / f"{word}{self.runs}")
                Path(word).parent.mkdir(parents=True, exist_ok=True)
            elif i and command.args[i - 1] == "--fingerprints" and not (self.checkout / word).exists():
                (self.checkout / word).write_text("")  # none recorded: each host would be refused, were it reached
            args.append(word)
        if command.program == "pyinfra":
            return pyinfra_argv(*args)
        if command.subcommand in doccommands.SHELL:  # man --install writes beside its Python's bin/
            return [str(self.environment()), "-m", "robotfleet", *args]
        return [sys.executable, "-m", "robotfleet", *args]

    def environment(self) -> Path:
        """A virtual environment of the sandbox's (the test runner's dependencies through a .pth,
        robotfleet the copy's, run from it): its Python."""
        python = self.base / "venv" / "bin" / "python"
        if not python.exists():
            venv.create(self.base / "venv", with_pip=False)
            purelib = subprocess.run(
                [python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                capture_output=True,
                text=True,
                check=True,
            ).stdout.strip()
            Path(purelib, "deps-of-the-test-runner.pth").write_text("\n".join(site.getsitepackages()) + "\n")
        return python

    def run(self, command: doccommands.Command) -> subprocess.CompletedProcess:
        env = self.env(command)
        result = subprocess.run(
            self.argv(command),
            cwd=self.checkout,
            env=env,
            capture_output=True,
            text=True,
            timeout=180,
            stdin=subprocess.DEVNULL,
        )
        result.env = env
        return result


@pytest.fixture(scope="module")
def sandbox(tmp_path_factory):
    return Sandbox(tmp_path_factory.mktemp("doc-commands"))


def unique_runnable():
    seen, found = set(), []
    for command in COMMANDS:
        if command.marker is None and doccommands.how_to_run(command):
            key = (tuple(command.argv), tuple(sorted(command.env.items())))
            if key not in seen:
                seen.add(key)
                found.append(command)
    return found


RUNNABLE = unique_runnable()


def test_the_runnable_commands_cover_the_operators_path():
    kinds = {doccommands.how_to_run(c)[0] for c in RUNNABLE}
    assert kinds == {"help", "generate", "keys-init", "unreachable", "inventory", "shell"}, kinds
    shown = {c.text for c in RUNNABLE}
    assert "robotfleet enroll inventories/robots.py" in shown and "pyinfra -y inventories/robots.py deploy.py" in shown


@pytest.mark.parametrize("command", RUNNABLE, ids=[f"{c.doc}:{c.line}" for c in RUNNABLE])
def test_each_command_that_needs_no_robot_runs_as_the_docs_say(command, sandbox):
    how, code = doccommands.how_to_run(command)
    result = sandbox.run(command)
    said = result.stdout + result.stderr
    assert "Traceback" not in said, f"{command.where}\n{said[-3000:]}"
    assert result.returncode == code, f"{command.where}: exit {result.returncode}, the docs say {code}\n{said[-3000:]}"
    if how in ("help", "inventory"):
        assert result.stdout.strip()
    elif how == "generate":
        for name in GENERATED:
            assert (sandbox.checkout / name).read_bytes() == (ROOT / name).read_bytes(), name
    elif how == "shell":
        written = re.match(r"(?:completion|man): (/[^:]+): ", result.stdout)
        if "--install" in command.args:
            assert written and Path(written[1]).is_file(), result.stdout
            assert str(sandbox.base) in written[1], written[1]  # the sandbox's, never this machine's own
        else:
            assert result.stdout.startswith(('.\\" robotfleet', "#compdef", "# robotfleet")), result.stdout[:200]
    elif how == "keys-init":
        keys = Path(result.env["ROBOTFLEET_KEYS"])
        for name in ("root.key", "online.key"):
            assert (keys / name).stat().st_mode & 0o777 == 0o600, name
    elif code == 2:
        assert "not a terminal; pass -y to start without asking" in result.stderr, result.stderr
    else:
        refused = f"connection refused by 127.0.0.1:{sandbox.port} (no SSH server listens on port {sandbox.port})"
        assert refused in said, f"{command.where}\n{said[-3000:]}"
        for path in [w for w in result.args if w.endswith(".prom")]:
            assert Path(path).read_text().endswith("# EOF\n"), path
        for path in [w for w in result.args if w.endswith(".html")]:  # status --html: the page, its hosts' rows
            page = (sandbox.checkout / path).read_text()
            assert page.startswith("<!DOCTYPE html>") and 'data-health="unreachable"' in page, path


def table_header(text: str) -> list[str]:
    return re.split(r"\s{2,}", text.strip())


def test_the_status_table_shown_is_the_one_status_prints(sandbox):
    """README's and docs/reference/status.md's example rows have status's columns."""
    command = doccommands.parse("test", 0, "robotfleet status inventories/robots.py")[0]
    printed = sandbox.run(command).stdout.splitlines()[0]
    shown = [
        line
        for doc in doccommands.documents()
        for block in doccommands.blocks(doc)
        for _, line in block.lines
        if line.startswith("HOST ")
    ]
    assert len(shown) >= 2
    for line in shown:
        assert table_header(line) == table_header(printed), line
