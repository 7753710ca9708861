"""End to end: docs/guides/pull-from-nothing.md's git server, from its own shell
blocks (issue 35 item 3), run as written on a stock Debian machine of the
lab: the host image (Debian 13, nothing of gitolite), on the lab network
under the guide's name for it, `git.example.com`, with the lab's apt proxy.

The guide's steps 1 to 3 are read from the guide (tests/doccommands.py
finds its blocks, as for every doc command) and run line by line as the
guide says: step 1 as root on the server, steps 2 and 3 as the operator
(`ops`, whose `~/.ssh/id_ed25519` is the admin key the guide's
`/path/to/your-key.pub` names).  Then robotfleet's own gitolite admin
(robotfleet/pull/operator/gitolite.py) registers a robot on that server,
as `bundle` and `pull-enroll` do, and the robot's key reads the fleet
repository: the guide's server is one robotfleet can run.

What the guide's later steps do (publish, the push deploy, pull-enroll,
status) is what tests/e2e/test_pull.py does on the lab's own gitolite
(tests/lab/gitserver.py: the same Debian package, set up from Python).
"""

from __future__ import annotations

import re
import shlex
import subprocess
import time
import uuid
from pathlib import Path

import pytest

from tests.e2e.conftest import phase
from tests.lab.state import exec_container

pytestmark = pytest.mark.e2e

GUIDE = "docs/guides/pull-from-nothing.md"
SERVER_NAME = "git.example.com"  # the guide's name for the git server
OPERATOR = "ops"
KEY_PATH = "/path/to/your-key.pub"  # the guide's placeholder, made a real file


def guide_blocks() -> dict[int, list[str]]:
    """The guide's indented and fenced shell blocks by the number of the
    step (``## N. ...``) they are in; comments kept (the shell drops them)."""
    from tests import doccommands

    doc = doccommands.ROOT / GUIDE
    headings = [
        (number, int(match.group(1)))
        for number, text in enumerate(doc.read_text().splitlines(), 1)
        if (match := re.match(r"^## (\d+)\. ", text))
    ]
    found: dict[int, list[str]] = {}
    for block in doccommands.blocks(doc):
        steps = [step for line, step in headings if line < block.line]
        text = "\n".join(line for _, line in block.lines).strip()
        if steps and block.marker is None and not text.startswith(("robots:", "robotfleet ")):
            found.setdefault(steps[-1], []).append(text)
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

    def known_hosts(self, path: Path) -> Path:
        path.write_text("".join(f"[127.0.0.1]:{self.port} {' '.join(k.split()[:2])}\n" for k in self.host_keys))
        return path

    def remove(self) -> None:
        self.container.remove(force=True)


@pytest.fixture(scope="module")
def server(lab):
    server = Server(lab)
    yield server
    server.remove()


def test_the_guide_s_git_server_is_made_by_its_own_commands_and_robotfleet_runs_it(server, tmp_path):
    from robotfleet.pull.operator import gitolite

    started = time.monotonic()
    steps = guide_blocks()
    assert [len(steps.get(n, [])) for n in (1, 2, 3)] == [1, 1, 2], steps  # the blocks this test runs
    assert server.root("id -u gitolite3 2>&1 || true").strip().startswith("id:")  # stock: no gitolite yet

    said = server.run(steps[1][0])  # step 1, on the server as root
    noted = re.findall(r"SHA256:[A-Za-z0-9+/]+", said)
    assert len(noted) == 1, said[-2000:]
    assert server.root("sudo -u gitolite3 -H git config --global receive.fsckObjects").strip() == "true"
    phase("pull guide: step 1, gitolite3 from Debian on a stock machine", started)
    # the same machine as the operator's (git is there now), with an operator's own git identity
    server.run("git config --global user.name Operator && git config --global user.email ops@example.com", OPERATOR)

    said = server.run(steps[2][0], OPERATOR)  # step 2: the server's key, compared with what step 1 noted
    assert re.findall(r"SHA256:[A-Za-z0-9+/]+", said) == noted, said
    server.run(steps[3][0], OPERATOR)  # step 3: the fleet's repository
    checkout = "mkdir -p fleet-deploy && cd fleet-deploy && git init -q && "
    server.run(checkout + steps[3][1], OPERATOR)  # named once in the operator's checkout
    info = server.run(f"ssh gitolite3@{SERVER_NAME} info", OPERATOR)
    assert "hello admin," in info and re.search(r"R W\s+fleet$", info, re.M), info  # the admin is `admin`
    remote = server.run("cd fleet-deploy && git config robotfleet.remote", OPERATOR).strip()
    assert remote == f"ssh://gitolite3@{SERVER_NAME}/fleet"
    server.run(f"git ls-remote {shlex.quote(remote)}", OPERATOR)  # it exists, and the operator reads it

    # robotfleet's admin of that server (as bundle and pull-enroll run it), from this machine
    admin = gitolite.Admin(
        f"ssh://gitolite3@127.0.0.1:{server.port}",
        server.lab.state["ssh_key"],
        str(server.known_hosts(tmp_path / "known_hosts")),
    )
    robot_key = tmp_path / "robot1"
    subprocess.run(["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-f", str(robot_key)], check=True)
    gitolite.register(admin, "fleet", "robot1", robot_key.with_suffix(".pub").read_text())
    ssh = (
        f"ssh -F /dev/null -i {robot_key} -o IdentitiesOnly=yes -o BatchMode=yes -o StrictHostKeyChecking=yes "
        f"-o UserKnownHostsFile={tmp_path / 'known_hosts'}"
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
    )
    assert "RW+ = admin" in conf and "robot1" in conf, conf  # the admin kept, the robot's rule added
    phase("pull guide: steps 2 and 3 as the operator, a robot registered by robotfleet", started)
