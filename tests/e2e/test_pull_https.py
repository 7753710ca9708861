"""End to end: a pull robot fetching its releases from a static HTTPS mirror
(issue 35 item 5; docs/guides/pull.md "Releases over HTTPS"), its reports going to
the lab's gitolite over SSH with its own key.

The mirror is what an operator would put near the robots: a copy of the
fleet remote (`git clone --mirror`, refreshed after each publish, then
`git update-server-info`: git's "dumb" protocol) served as static files
over TLS by the integration tests' server (tests/integration/httpsgit.py),
its certificate from a CA made for this module and given to the robot as
`pull_remote_ca`.  The server runs in this process on the lab network's
gateway address, which the robots reach and nothing else does.

One robot of the session's lab (robot2), its own pull agent installed by a
push deploy run from the operator's deploy repository (where
`pull_remote_ca` is a file of the deploy tree, as for a user), its timer at
an hour (every check here is started by the test).  It starts from nothing
of pull mode on that robot or the fleet remote and removes what it made at
its end, so it may run before or after the other pull modules.
"""

from __future__ import annotations

import subprocess
import time

import pytest

from tests.e2e.conftest import phase
from tests.e2e.pullmode import Pull, by_digest, clear_remote
from tests.fixtures import pyinfra

pytestmark = pytest.mark.e2e

ROBOT = "robot2"
CA_FILE = "files/e2e-mirror-ca.pem"  # pull_remote_ca: a path in the deploy tree
QUIET = {"payload_health_timeout": 20, "payload_stable_seconds": 2, "pull_interval": 3600, "pull_jitter": 0}
RESET = "systemctl disable --now robot-pull.timer; rm -rf /etc/robot-pull /var/lib/robot-pull"


class Mirror:
    """A static copy of the fleet remote served over HTTPS on ``address``."""

    def __init__(self, world, address: str):
        from tests.integration import httpsgit

        self.world, self.httpsgit = world, httpsgit
        self.root = world.op.base / "mirror"
        self.repo = self.root / "fleet.git"
        self.ca, self.cert, self.key = httpsgit.make_ca(world.op.base / "tls", address)
        self.address, self.server = address, None

    def git(self, *args: str) -> str:
        done = subprocess.run(["git", *args], capture_output=True, text=True, env=self.world.op.env())
        assert done.returncode == 0, f"git {' '.join(args[:3])}: {done.stderr}"
        return done.stdout

    def sync(self) -> None:
        """The mirror made the fleet remote's copy again (releases branch and reports)."""
        from tests.lab import gitserver

        if not self.repo.exists():
            self.git("clone", "-q", "--mirror", gitserver.local_url(self.world.op.git), str(self.repo))
        self.git("-C", str(self.repo), "fetch", "-q", "--prune", "origin")
        self.published()

    def published(self) -> None:
        """What a static server needs after a change: git's info/refs and objects/info/packs."""
        self.git("-C", str(self.repo), "update-server-info")

    def serve(self, cert=None, key=None, port: int = 0) -> None:
        self.server = self.httpsgit.Server(
            self.root, cert or self.cert, key or self.key, smart=False, host=self.address, port=port
        )

    def close(self) -> None:
        if self.server is not None:
            self.server.close()
            self.server = None

    def url(self) -> str:
        return self.server.url("fleet.git")


class Https(Pull):
    def fleet(self, tag: str, robots=(ROBOT,), **more) -> str:
        from tests.lab import gitserver

        return self.pullfleet.fleet_text(
            self.op.lab,
            payload_tag=tag,
            robots=list(robots),
            **{
                **QUIET,
                "pull_remote": self.mirror.url(),
                "pull_remote_ca": CA_FILE,
                "pull_report_remote": gitserver.robot_url(self.op.git),
                **more,
            },
        )

    def check(self) -> None:
        self.trigger([ROBOT])

    def report(self) -> dict:
        return self.reports()[ROBOT]

    def push_deploy(self) -> None:
        """pyinfra from the operator's deploy repository, as a user runs it
        (the deploy tree's pull_remote_ca is read there)."""

        started = time.monotonic()
        env = self.op.env(ROBOT_LAB_FLEET=str(self.op.repo / self.pullfleet.FLEET), PYINFRA_PROGRESS="off")
        done = pyinfra(
            "-y", f"--limit={ROBOT}", "inventories/lab.py", "deploy.py", cwd=self.op.repo, env=env, timeout=1500
        )
        phase(f"pyinfra deploy.py (pull agent, https mirror; exit {done.returncode})", started)
        assert done.returncode == 0, (done.stderr + done.stdout)[-4000:]


def gateway(prefix: str) -> str:
    """The lab network's gateway: this machine as the lab's hosts reach it."""
    from tests.lab.engine import client

    return client().networks.get(f"{prefix}-net").attrs["IPAM"]["Config"][0]["Gateway"]


@pytest.fixture(scope="module")
def world(lab, tmp_path_factory):
    started = time.monotonic()
    world = Https(lab, tmp_path_factory.mktemp("pull-https"))
    op = world.op
    lab.ok(ROBOT, RESET)
    clear_remote(world)
    op.setup()
    world.mirror = Mirror(world, gateway(lab.prefix))
    world.mirror.serve()
    (op.repo / CA_FILE).parent.mkdir(exist_ok=True)
    (op.repo / CA_FILE).write_bytes(world.mirror.ca.read_bytes())
    try:
        op.publish(world.fleet("1.0"), "release 1", "--pause", "0")
        world.mirror.sync()
        world.push_deploy()
        op.register_robots([ROBOT])  # its own key writes its reports on gitolite
        world.check()
        report = world.report()
        assert report["result"] in ("applied", "up-to-date") and report["applied"]["version"] == 1, report
        phase("pull https: release 1 by push, the agent on the mirror, its key on gitolite", started)
        yield world
    finally:
        world.mirror.close()
        lab.sh(ROBOT, RESET)
        clear_remote(world)


def test_a_robot_converges_from_a_static_https_mirror_and_reports_to_gitolite_over_ssh(world, lab):
    started, op = time.monotonic(), world.op
    config = lab.ok(ROBOT, "cat /etc/robot-pull/agent.json")
    assert world.mirror.url() in config and "ssh://" in config, config  # fetch over HTTPS, report over SSH
    assert lab.ok(ROBOT, "cat /etc/robot-pull/remote-ca.pem") == world.mirror.ca.read_text()
    op.publish(world.fleet("1.1"), "release 2: payload 1.1", "--no-wheels", "--pause", "0")
    world.mirror.sync()
    requests = world.mirror.server.requests
    world.check()
    assert world.mirror.server.requests > requests  # the release came from the mirror
    report = world.report()  # from gitolite: the mirror is read-only
    assert report["result"] == "applied" and report["applied"]["version"] == 2, report
    ref = world.pullfleet.pinned(op.lab, "ros/payload", "1.1")
    assert lab.version(ROBOT) == "1.1"
    payload = lab.payload(ROBOT)
    assert payload["Config"]["Image"] == by_digest(ref), payload["Config"]["Image"]  # run by the digest
    assert lab.ok(ROBOT, f"docker image inspect -f '{{{{.Id}}}}' {by_digest(ref)}").strip() == payload["Image"]
    assert ref in lab.ok(ROBOT, "cat /var/lib/robot-payload/current/record.json")  # keyed with its tag
    status = op.status("--limit", ROBOT, "-o", "wide", *op.remote())
    assert status.returncode == 0, status.stdout + status.stderr
    line = next(line for line in status.stdout.splitlines() if line.startswith(ROBOT + " "))
    assert " pull " in line and "applied 2 " in line, status.stdout
    assert f" {ref.split('@')[0]}@{ref.split('@')[1][:19]} " in line, status.stdout  # the tag kept
    phase("pull https: release 2 from the mirror, reported on gitolite", started)


def test_a_tampered_mirror_and_a_server_outside_the_fleet_s_ca_change_nothing(world, lab):
    from robotfleet.pull.operator.repository import Repository

    started, mirror = time.monotonic(), world.mirror
    before, running = lab.record(ROBOT), lab.version(ROBOT)
    version = Repository(world.op.base / "releases").record().version

    # the mirror serves the current release with its record changed after it was signed
    world.attacks.url = str(mirror.repo)
    good = world.attacks.checkout()
    world.attacks.tamper()
    mirror.published()
    try:
        world.check()
        report = world.report()
        assert (report["result"], report.get("refusal")) == ("refused", "tampered"), report
        assert lab.version(ROBOT) == running and lab.record(ROBOT) == before
    finally:
        world.attacks.restore(good)
        mirror.published()

    # the same address and port, a certificate from another CA than pull_remote_ca
    port = mirror.server.port
    other = mirror.httpsgit.make_ca(world.op.base / "other-tls", mirror.address)
    mirror.close()
    mirror.serve(other[1], other[2], port)
    try:
        world.check()
        report = world.report()
        assert report["result"] == "failed" and "certificate" in report["reason"], report
        assert mirror.server.requests == 0  # refused in the TLS handshake: no request made
        assert lab.version(ROBOT) == running and lab.record(ROBOT) == before
        assert report["applied"]["version"] == version, report
    finally:
        mirror.close()
        mirror.serve(port=port)
    world.check()  # the good mirror again: nothing new to apply
    assert world.report()["result"] == "up-to-date", world.report()
    phase("pull https: tampered mirror and foreign certificate refused", started)
