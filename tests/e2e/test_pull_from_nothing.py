"""End to end: docs/guides/pull-from-nothing.md followed as a new user would,
steps 1 to 8 (issue 35 item 3): from a stock Debian machine to a pull robot
that applies a signed release and reports it.

The guide's blocks are read from the guide (tests/doccommands.py finds them,
as for every doc command) and run as a shell runs them, stopping at the first
failure: a wrong flag or a missing step fails the test.  Steps 1 to 3 on the
git server, the lab's stock host image (nothing of gitolite) on the lab
network under the guide's name, `git.example.com`: step 1 as root, 2 and 3 as
the operator (`ops`, whose `~/.ssh/id_ed25519` is the guide's
`/path/to/your-key.pub`); robotfleet's gitolite admin registers a robot there.
Steps 3 to 8 as the operator on this machine, in a checkout of this
repository with a home of its own (no git identity until step 3 gives one):
keys (4), the fleet file and the robot's own pull_platform (5), the commit and
publish with its defaults (6), enroll on a terminal, the push deploy and
pull-enroll (7; its first-boot bundle is tests/e2e/test_pull.py's), the
robot's check and status (8): `applied`, exit 0.  Only what must differ in
the lab is substituted (LAB below, each once).

One robot, the session's ROBOT, provisioned by the first run: the push deploy
adds only the agent.  Its python3 is Ubuntu 24.04's 3.12 (this machine's
build, tests/lab/robot_python.py), not the lab's 3.13, as on most robots a
guide's reader has (issue 51): publish fetches its cp312 wheels, its agent's
venv and the converge it runs are 3.12's, and so is its payloadctl.  Its
check is started directly (the timer's first ran at the install, before
pull-enroll registered its key; its next is 900 s later).
At the end its agent is removed and a push deploy of the lab's fleet gives it
back its payload by tag.  Cost: docs/guides/development.md.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest
import yaml

from tests import doccommands
from tests.e2e.conftest import ROOT, phase
from tests.e2e.pullmode import CHECK_NOW
from tests.fixtures import PYINFRA
from tests.lab.state import exec_container

pytestmark = pytest.mark.e2e

GUIDE = "docs/guides/pull-from-nothing.md"
SERVER_NAME = "git.example.com"  # the guide's name for the git server
OPERATOR = "ops"
KEY_PATH = "/path/to/your-key.pub"  # the guide's placeholder, made a real file
ROBOT = "robot3"  # of the session's lab: robot1 is test_arm64.py's as the first run left it
RESET = (
    "systemctl disable --now robot-pull.timer; rm -rf /etc/robot-pull /var/lib/robot-pull "
    "/etc/systemd/system/robot-pull.service /etc/systemd/system/robot-pull.timer; systemctl daemon-reload"
)
# LAB: what differs in the lab, each substituted in one place; the rest of every block is the guide's.
#   - the robots (step 5): the guide's robot1 and robot2 at 10.20.0.x are ROBOT, at 127.0.0.1 on its lab
#     port with the lab key, with its settings and the lab's (apt mirror, registry) under the guide's:
#     lab_fleet_file; the guide's host key placeholder is step 2's line (HOST_KEY)
#   - the registry (step 5): GUIDE_IMAGE is the lab registry's LAB_IMAGE; this machine resolves the
#     robots' name for it through a proxy (Operator.proxy), as the guide's /etc/hosts line would
#   - the git server from this machine: 127.0.0.1 on its lab port; the operator's SSH config says so
#     (Operator.ssh_config: ssh reads the user's real home, not $HOME), and so does --admin (lab_commands)
#   - the robot's python3 is ROBOT_PYTHON, Ubuntu 24.04's, whose pull_platform the guide's example gives
#   - the operator's robotfleet and pyinfra: this venv's, running the operator's checkout (Operator.bin),
#     as a venv installed from that checkout would; publish's wheels from a cache of the lab's (~/.cache)
HOST_KEY = '"ssh-ed25519 AAAA..."'
GUIDE_IMAGE = "registry.lan:5000/payload:1"
LAB_IMAGE = "ros/payload:1.0"  # the first run's (inventories/lab.yaml)
ROBOT_PYTHON = "3.12"
ROBOT_PLATFORM = "cp312-x86_64"


def guide_blocks() -> dict[int, list[str]]:
    """Each of the guide's indented and fenced blocks (shell and YAML, marked
    illustrative or not) by the number of the step (``## N. ...``) they are
    in; comments kept (the shell drops them)."""
    doc = doccommands.ROOT / GUIDE
    headings = [
        (number, int(match.group(1)))
        for number, text in enumerate(doc.read_text().splitlines(), 1)
        if (match := re.match(r"^## (\d+)\. ", text))
    ]
    found: dict[int, list[str]] = {}
    for block in doccommands.blocks(doc):
        steps = [step for line, step in headings if line < block.line]
        if steps and block.lines:
            found.setdefault(steps[-1], []).append("\n".join(line for _, line in block.lines).strip())
    return found


class Server:
    """A stock Debian machine on the lab network, named as the guide names its git server."""

    def __init__(self, lab):
        from tests.lab import hostimage, sshd
        from tests.lab.engine import client, pick_free_port, published_ports, put_files

        self.lab, dc = lab, client()
        self.name = f"{lab.prefix}-guide-git"
        old = dc.containers.list(all=True, filters={"name": f"^{self.name}$"})
        for container in old:
            container.remove(force=True)
        self.port = pick_free_port(24001, published_ports(dc))
        network = f"{lab.prefix}-net"
        self.container = hostimage.create_systemd_container(
            dc,
            hostimage.ensure_host_image(dc),
            self.name,
            hostname="git",
            network=network,
            labels={"robot-lab.prefix": lab.prefix, "robot-lab.role": "guide-git"},
            ports={22: self.port},
            volumes={},
        )
        dc.networks.get(network).disconnect(self.container)  # again, under the guide's name
        dc.networks.get(network).connect(self.container, aliases=[SERVER_NAME])
        proxy = lab.ok(lab.robots[0], "cat /etc/apt/apt.conf.d/01robot-lab-proxy")
        put_files(
            self.container, {"/etc/machine-id": uuid.uuid4().hex + "\n", "/etc/apt/apt.conf.d/01robot-lab-proxy": proxy}
        )
        self.container.start()
        self.host_keys = sshd.wait_for_host_keys(self.container, 90)
        key = Path(lab.state["ssh_key"])
        home = f"/home/{OPERATOR}"
        self.root(f"mkdir -p {Path(KEY_PATH).parent} {home}/.ssh")
        put_files(self.container, {KEY_PATH: key.with_suffix(".pub").read_text()})
        put_files(
            self.container,
            {
                f"{home}/.ssh/id_ed25519": key.read_text(),
                f"{home}/.ssh/id_ed25519.pub": key.with_suffix(".pub").read_text(),
            },
            mode=0o600,
        )
        self.root(f"chown -R {OPERATOR}: {home}/.ssh && chmod 700 {home}/.ssh")

    def run(self, script: str, user: str = "root") -> str:
        """A block of the guide, line by line as a shell runs it, stopping at the first failure."""
        wrapped = f"set -e\n{script}\n"
        argv = ["sh", "-c", wrapped] if user == "root" else ["su", "-", user, "-c", wrapped]
        code, text = exec_container(self.container, argv)
        assert code == 0, f"{GUIDE} ({user}): exit {code}:\n{script}\n---\n{text[-3000:]}"
        return text

    def root(self, command: str) -> str:
        return self.run(command)

    def known_hosts_lines(self) -> str:
        """Its host keys as this machine reaches it (127.0.0.1, its lab port)."""
        return "".join(f"[127.0.0.1]:{self.port} {' '.join(k.split()[:2])}\n" for k in self.host_keys)

    def remove(self) -> None:
        self.container.remove(force=True)


class Operator:
    """The guide's operator on this machine, from step 3 on: a checkout of
    this repository (its tracked files) and a home of its own ($HOME: the
    keys, pip's cache, ~/.ssh), with the lab's substitutions (LAB above)."""

    def __init__(self, server: Server, base: Path):
        from tests.lab import pullfleet
        from tests.lab.registryproxy import RegistryProxy

        self.server, self.home, self.checkout, self.bin = server, base / "home", base / "checkout", base / "bin"
        ssh = self.home / ".ssh"
        ssh.mkdir(parents=True, mode=0o700)
        key = ssh / "id_ed25519"
        shutil.copy(server.lab.state["ssh_key"], key)
        key.chmod(0o600)
        # the known_hosts step 2 made (git.example.com); the same keys at the lab's address, for --admin
        made = server.run("cat .ssh/known_hosts", OPERATOR)
        (ssh / "known_hosts").write_text(made + server.known_hosts_lines())
        self.ssh_config = ssh / "config"
        self.ssh_config.write_text(
            f"Host {SERVER_NAME}\n  HostName 127.0.0.1\n  Port {server.port}\n  HostKeyAlias {SERVER_NAME}\n"
            f"  IdentityFile {key}\n  IdentitiesOnly yes\n  UserKnownHostsFile {ssh / 'known_hosts'}\n"
            "  StrictHostKeyChecking yes\n  BatchMode yes\n"
        )
        # a wheel cache of its own (two publishes sharing one race on pip's log there), the pull group's copied
        wheels, pulled = ROOT / ".lab" / "cache" / "pull-guide-wheels", ROOT / ".lab" / "cache" / "pull-wheels"
        if pulled.is_dir():
            shutil.copytree(pulled, wheels, dirs_exist_ok=True, ignore=shutil.ignore_patterns("*.log"))
        wheels.mkdir(parents=True, exist_ok=True)
        (self.home / ".cache" / "robotfleet").mkdir(parents=True)
        (self.home / ".cache" / "robotfleet" / "wheels").symlink_to(wheels)
        self.bin.mkdir()
        for name, args in {"robotfleet": "-m robotfleet", "pyinfra": f"-c {shlex.quote(PYINFRA)}"}.items():
            (self.bin / name).write_text(f'#!/bin/sh\nexec {shlex.quote(sys.executable)} {args} "$@"\n')
            (self.bin / name).chmod(0o755)
        self.proxy = RegistryProxy(server.lab.state["registry"], server.lab.state["registry_local"])
        pullfleet.copy_tracked(self.checkout)
        self.git("init", "-q", "-b", "main")
        # the deploy repository as the operator cloned it: its history is upstream's, not the operator's
        upstream = ("-c", "user.name=Upstream", "-c", "user.email=upstream@example.com")
        self.git("add", "-A")
        self.git(*upstream, "commit", "-q", "-m", "the deploy repository, as cloned")

    def env(self) -> dict:
        unset = ("ROBOTFLEET_", "ROBOT_FLEET", "ROBOT_LAB_", "XDG_", "GIT_", "SSH_AUTH_SOCK")
        env = {name: value for name, value in os.environ.items() if not name.startswith(unset)}
        return dict(
            env,
            HOME=str(self.home),
            PATH=f"{self.bin}:{env['PATH']}",
            GIT_SSH_COMMAND=f"ssh -F {self.ssh_config}",
            GIT_CONFIG_NOSYSTEM="1",  # the identity is the guide's (step 3), never this machine's
            PYINFRA_PROGRESS="off",
            **self.proxy.env(),
        )

    def git(self, *args: str) -> str:
        done = subprocess.run(["git", *args], cwd=self.checkout, env=self.env(), capture_output=True, text=True)
        assert done.returncode == 0, f"git {' '.join(args)}: {done.stderr}"
        return done.stdout

    def run(
        self, block: str, what: str, substitutions: dict | None = None, answer: str = "", terminal: bool = False
    ) -> str:
        """A block of the guide in the checkout, as a shell runs it (stopping at the first failure), with
        ``substitutions`` made; ``answer`` on its stdin (pyinfra's Enter), typed ahead on a pseudo-terminal
        with ``terminal`` (enroll asks only on a terminal)."""
        started = time.monotonic()
        script = substituted(block, substitutions or {})
        argv = ["bash", "-c", f"set -e\n{script}\n"]
        if terminal:
            import pty

            typed, stdin = pty.openpty()
            os.write(typed, answer.encode())
            try:
                done = subprocess.run(
                    argv, cwd=self.checkout, env=self.env(), stdin=stdin, capture_output=True, text=True, timeout=1500
                )
            finally:
                os.close(stdin)
                os.close(typed)
        else:
            done = subprocess.run(
                argv, cwd=self.checkout, env=self.env(), input=answer, capture_output=True, text=True, timeout=1500
            )
        phase(f"pull guide: {what} (exit {done.returncode})", started)
        said = done.stdout + done.stderr
        assert done.returncode == 0, f"{GUIDE}, {what}: exit {done.returncode}:\n{script}\n---\n{said[-4000:]}"
        return said

    def close(self) -> None:
        self.proxy.close()


def substituted(text: str, substitutions: dict[str, str]) -> str:
    for old, new in substitutions.items():
        assert old in text, f"{GUIDE} no longer says {old!r}: the lab's substitution for it (LAB) is stale"
        text = text.replace(old, new)
    return text


def lab_commands(server: Server) -> dict[str, str]:
    """The commands' substitutions: gitolite's admin as this machine reaches it (the guide's name for the
    server resolves on the lab network only; its operator's own SSH is told by its ~/.ssh/config)."""
    return {f"--admin ssh://gitolite3@{SERVER_NAME} ": f"--admin ssh://gitolite3@127.0.0.1:{server.port} "}


def lab_fleet_file(block: str, lab, key_line: str, known_hosts: Path) -> str:
    """Step 5's fleet file as the lab needs it: its robots (robot1 and robot2 at
    10.20.0.x) are ROBOT, reached at its lab port with the lab key and with its
    settings of inventories/lab.yaml; its registry is the lab registry's
    LAB_IMAGE; the lab's own settings (its apt mirror, its registry as an
    insecure one) under the guide's; the host key is step 2's line."""
    from tests.lab import pullfleet

    text = substituted(block, {HOST_KEY: key_line, GUIDE_IMAGE: f"{lab.state['registry']}/{LAB_IMAGE}"})
    guide = yaml.safe_load(text)
    assert list(guide) == ["robots"] and list(guide["robots"]) == ["vars", "hosts"], guide
    assert all(list(data) == ["address"] for data in guide["robots"]["hosts"].values()), guide
    base = pullfleet.lab_fleet(lab.state)
    port = next(h["port"] for h in lab.state["hosts"] if h["name"] == ROBOT)
    robot = {
        **(base["robots"]["hosts"].get(ROBOT) or {}),
        "address": "127.0.0.1",
        "ssh_port": port,
        "ssh_key": lab.state["ssh_key"],
        "ssh_known_hosts_file": str(known_hosts),
    }
    robots = {"vars": {**base["robots"]["vars"], **guide["robots"]["vars"]}, "hosts": {ROBOT: robot}}
    # JSON is YAML 1.2, and quotes every string ("0825" stays text).
    return f"# {GUIDE}'s fleet on the lab ({Path(__file__).name}).\n" + json.dumps(
        {"all": base["all"], "robots": robots}, indent=1
    )


@pytest.fixture(scope="module")
def server(lab):
    server = Server(lab)
    yield server
    server.remove()


@pytest.fixture(scope="module")
def made(server):
    """The guide's steps 1 to 3: the git server, the operator's SSH to it, the fleet's repository."""
    started = time.monotonic()
    steps = guide_blocks()
    assert [len(steps.get(n, [])) for n in range(1, 9)] == [1, 1, 3, 1, 2, 2, 2, 1], steps  # the guide's blocks
    assert server.root("id -u gitolite3 2>&1 || true").strip().startswith("id:")  # stock: no gitolite yet

    said = server.run(steps[1][0])  # step 1, on the server as root
    noted = re.findall(r"SHA256:[A-Za-z0-9+/]+", said)
    assert len(noted) == 1, said[-2000:]
    assert server.root("sudo -u gitolite3 -H git config --global receive.fsckObjects").strip() == "true"
    exempt = server.root("sshd -T 2>&1 | grep -i '^persourcepenaltyexemptlist' || true")
    assert "192.168.0.0/16" in exempt, exempt  # the guide's exemption, taken by this Debian 13 sshd
    phase("pull guide: step 1, gitolite3 from Debian on a stock machine", started)
    # the same machine as the operator's (git is there now)
    said = server.run(steps[2][0], OPERATOR)  # step 2: the server's key, compared with what step 1 noted
    assert re.findall(r"SHA256:[A-Za-z0-9+/]+", said) == noted, said
    assert server.run("git config --global user.email || true", OPERATOR).strip() == ""  # no identity yet
    server.run(steps[3][0], OPERATOR)  # step 3: the operator's git identity
    server.run(steps[3][1], OPERATOR)  # the fleet's repository
    checkout = "mkdir -p fleet-deploy && cd fleet-deploy && git init -q && "
    server.run(checkout + steps[3][2], OPERATOR)  # named once in the operator's checkout
    phase("pull guide: steps 2 and 3 as the operator", started)
    return steps


def test_the_guide_s_git_server_is_made_by_its_own_commands_and_robotfleet_runs_it(server, made, tmp_path):
    from robotfleet.pull.operator import gitolite

    started = time.monotonic()
    info = server.run(f"ssh gitolite3@{SERVER_NAME} info", OPERATOR)
    assert "hello admin," in info and re.search(r"R W\s+fleet$", info, re.M), info  # the admin is `admin`
    remote = server.run("cd fleet-deploy && git config robotfleet.remote", OPERATOR).strip()
    assert remote == f"ssh://gitolite3@{SERVER_NAME}/fleet"
    server.run(f"git ls-remote {shlex.quote(remote)}", OPERATOR)  # it exists, and the operator reads it

    # robotfleet's admin of that server (as bundle and pull-enroll run it), from this machine
    known_hosts = tmp_path / "known_hosts"
    known_hosts.write_text(server.known_hosts_lines())
    admin = gitolite.Admin(f"ssh://gitolite3@127.0.0.1:{server.port}", server.lab.state["ssh_key"], str(known_hosts))
    robot_key = tmp_path / "robot1"
    subprocess.run(["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-f", str(robot_key)], check=True)
    gitolite.register(admin, "fleet", "robot1", robot_key.with_suffix(".pub").read_text())
    ssh = (
        f"ssh -F /dev/null -i {robot_key} -o IdentitiesOnly=yes -o BatchMode=yes -o StrictHostKeyChecking=yes "
        f"-o UserKnownHostsFile={known_hosts}"
    )
    read = subprocess.run(
        ["git", "ls-remote", f"ssh://gitolite3@127.0.0.1:{server.port}/fleet"],
        env={"GIT_SSH_COMMAND": ssh, "PATH": "/usr/bin:/bin"},
        capture_output=True,
        text=True,
    )
    assert read.returncode == 0, read.stderr  # the robot's key reads the fleet's releases
    conf = server.root(
        "sudo -u gitolite3 -H git -C /var/lib/gitolite3/repositories/gitolite-admin.git show HEAD:conf/gitolite.conf"
        " HEAD:conf/robotfleet/fleet.conf"
    )
    assert "RW+ = admin" in conf and "robot1" in conf, conf  # the admin kept, the robot's rule added
    phase("pull guide: a robot registered by robotfleet", started)


@pytest.fixture(scope="module")
def operator(server, made, lab, first_run, tmp_path_factory):
    from tests import pythons
    from tests.lab import robot_python

    said = robot_python.install(f"{lab.prefix}-{ROBOT}", pythons.require(ROBOT_PYTHON))
    assert said.startswith(f"Python {ROBOT_PYTHON}."), said
    operator = Operator(server, tmp_path_factory.mktemp("pull-guide"))
    yield operator
    operator.close()
    robot_python.restore(f"{lab.prefix}-{ROBOT}", ROBOT_PYTHON)
    lab.sh(ROBOT, RESET)  # the robot as the session's first run left it, for the modules after this one
    run = lab.provision(f"--limit={ROBOT}", label=f"({ROBOT} back to the lab's fleet)")
    assert run.returncode == 0, run.output[-4000:]


def test_the_guide_s_steps_4_to_8_give_a_pull_robot_that_applies_and_reports(server, made, operator, lab):
    started, steps = time.monotonic(), made
    operator.run(steps[3][0], "step 3, the operator's git identity on this machine")
    operator.run(steps[3][2], "step 3, the remote named in the operator's checkout")
    operator.run(steps[4][0], "step 4, the signing keys")
    keys = operator.home / ".config" / "robotfleet" / "keys"
    assert {p.name: p.stat().st_mode & 0o777 for p in keys.glob("*.key")} == {"root.key": 0o600, "online.key": 0o600}

    written = server.run("cat /tmp/git.key", OPERATOR).splitlines()  # step 2's key line, without the host name
    key_line = next(line.split(None, 1)[1] for line in written if line.startswith(f"{SERVER_NAME} ssh-ed25519 "))
    known_hosts = operator.home / "robots_known_hosts"  # the robots' host keys: none until step 7's enroll
    known_hosts.touch()
    fleet = lab_fleet_file(steps[5][0], lab, key_line, known_hosts)
    # the guide's pull_platform is this robot's, as the robot itself says with the guide's command
    assert yaml.safe_load(steps[5][0])["robots"]["vars"]["pull_platform"] == ROBOT_PLATFORM
    assert lab.ok(ROBOT, steps[5][1]).strip() == ROBOT_PLATFORM
    (operator.checkout / "inventories" / "robots.yaml").write_text(fleet)
    operator.run(steps[6][0], "step 6, the fleet file committed")
    assert "inventories/robots.yaml" in operator.git("show", "--name-only", "--format=%an <%ae>", "HEAD")
    assert operator.git("status", "--porcelain", "inventories/robots.yaml") == ""

    said = operator.run(steps[6][1], "step 6, publish with the defaults")
    registry = lab.state["registry"]
    assert f"GET http://{registry}/v2/{LAB_IMAGE.split(':')[0]}/manifests/1.0" in operator.proxy.requests
    # one robot: the canary is the release's only wave, so the default pause (900 + 300 s) never holds it
    assert "1 wave(s); wave k opens at publish + k x 1200 s" in said and "(--max-failed 0)" in said, said
    assert re.search(rf"^publish:   wave 0 \(canary\): 1 robot\(s\) from \S+: {ROBOT}$", said, re.M), said

    # enroll asks on the terminal (y: the fingerprint compared), then pyinfra waits for Enter
    said = operator.run(
        steps[7][0], "step 7, enroll, the push deploy and pull-enroll", lab_commands(server), "y\n\n", terminal=True
    )
    shown = re.search(rf"{ROBOT} \([^)]*\) \S+ (SHA256:\S+): enrolled$", said, re.M)
    assert shown and known_hosts.read_text().strip(), said[-3000:]
    # the fingerprint it asked about is the one the guide says to compare: the robot's own ssh-keygen -lf
    assert shown[1] in lab.ok(ROBOT, "for k in /etc/ssh/ssh_host_*_key.pub; do ssh-keygen -lf $k; done")
    assert f"{ROBOT}: its own key is now registered" in said, said[-3000:]
    # its check now, not at its timer's next: the timer's first ran at the install, before its key was registered
    code, said = lab.sh(ROBOT, CHECK_NOW)
    assert code == 0, said + lab.ok(ROBOT, "journalctl -u robot-pull.service --no-pager | tail -40")

    said = operator.run(steps[8][0], "step 8, status")
    row = next((line for line in said.splitlines() if line.startswith(f"{ROBOT} ")), None)
    assert row is not None and " pull " in row, said
    applied = row.endswith(" applied 1") or (
        row.endswith(" up-to-date 1")  # a timer's check after ours
        and "applied (release 1)" in lab.ok(ROBOT, "journalctl -u robot-pull.service --no-pager")
    )
    assert applied, said
    said = operator.run(f"{steps[8][0]} -o wide", "step 8, status -o wide")
    row = next((line for line in said.splitlines() if line.startswith(f"{ROBOT} ")), "")
    assert f" {registry}/{LAB_IMAGE}@sha256:" in row, said  # by its digest, the tag kept
    # the applying wake's journal line says where its seconds went, the converge's deploy and status read included
    journal = lab.ok(ROBOT, "journalctl -u robot-pull.service -o cat --no-pager")
    took = re.search(r"^robot-pull: applied \(release 1\).*; report sent \[(.*)\]$", journal, re.M)
    names = [part.split(" ")[0] for part in took[1].split(", ")] if took else None
    assert names == ["fetch", "verify", "decide", "prepare", "load", "deploy", "status", "report"], journal
    # all of it on the robot's own Python: the agent's venv, the converge's deploy, payloadctl
    agent = lab.ok(ROBOT, "/var/lib/robot-pull/venv/bin/python -c 'import sys, pyinfra; print(sys.version_info[:2])'")
    assert agent.strip() == str(tuple(int(n) for n in ROBOT_PYTHON.split("."))), agent
    assert lab.ok(ROBOT, "readlink -f /usr/bin/python3").strip() == f"/usr/bin/python{ROBOT_PYTHON}"
    # step 8's halt, in its prose, signed with the defaults too
    halt = next(c.text for c in doccommands.inline_commands(ROOT / GUIDE) if c.subcommand == "halt")
    said = operator.run(halt, "step 8, halt", {'"..."': "'the guide, end to end'"})
    assert re.search(r"^halt: release 2 halts commit \w+ \(the guide, end to end\)", said, re.M), said
    phase("pull guide: steps 4 to 8 on this machine, the robot applied release 1", started)


def test_a_robot_whose_python_is_too_old_for_pull_mode_is_refused_before_anything_changes(operator, lab):
    """Ubuntu 20.04's 3.8 as the robot's python3: step 7's push deploy refuses it in one line naming its
    Python and the way out, before any role changes anything on it."""
    from tests import pythons
    from tests.lab import robot_python

    started, container = time.monotonic(), f"{lab.prefix}-{ROBOT}"
    robot_python.restore(container, ROBOT_PYTHON)
    assert robot_python.install(container, pythons.require("3.8")).startswith("Python 3.8.")
    kept = "ls -l --time-style=+%s.%N /etc/robot-pull /etc/systemd/system/robot-pull.* /var/lib/robot-pull"
    before = lab.ok(ROBOT, kept)
    try:
        done = subprocess.run(
            ["bash", "-c", "pyinfra -y inventories/robots.py deploy.py"],
            cwd=operator.checkout,
            env=operator.env(),
            capture_output=True,
            text=True,
            timeout=600,
        )
        said = done.stdout + done.stderr
        line = (
            "this robot's python3 3.8 is too old for pull mode (the robot runs pyinfra 3, which needs Python 3.10 "
            "or later): provision it by push (pull_enabled: false), or give it a python3 of 3.10 or later"
        )
        assert done.returncode != 0 and line in said, said[-3000:]
        named = {text.strip() for text in said.splitlines() if "too old for pull mode" in text}
        assert len(named) == 1 and ROBOT in next(iter(named)), said  # one line, naming the robot
        assert lab.ok(ROBOT, kept) == before  # the agent, its units and its venv as they were
    finally:
        robot_python.restore(container, "3.8")
        robot_python.install(container, pythons.require(ROBOT_PYTHON))  # as the module's teardown expects it
    phase("pull guide: a robot on Python 3.8 refused", started)
