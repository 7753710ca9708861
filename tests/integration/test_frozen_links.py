"""A link that freezes under an open connection (issue 51, item 2): the
connection stays open and delivers nothing, which TCP never reports.  The
operator's connector gives it up after ``ssh_keepalive_count_max``
unanswered keepalives: the command waiting on it fails its host with one
line naming the host and the frozen link, the other hosts finish, the run
ends.  A real SSH server on 127.0.0.1 (tests/integration/sshserver.py)
behind the lab's fault-injecting proxy (tests/lab/linkproxy.py), the
operator's commands run as their users run them.  Before: the run waited
for ever (each test bounds its command, so it fails instead)."""

from __future__ import annotations

import json
import threading
import time

import pytest

from robotfleet import hostkeys
from tests.fixtures import PYINFRA
from tests.integration import sshserver
from tests.integration.operator_side import fleet, run
from tests.lab.linkproxy import Link

INTERVAL, COUNT = 1, 2
# Given up after (COUNT + 1) intervals of silence (OpenSSH's rule), each looked at within the
# connector's idle wake-up (the interval here): what a loaded machine adds is the margin.
BOUND = (COUNT + 2) * INTERVAL + 15  # far under HOLD: a loaded machine (load 8 on 2 cores) took 14.8 s
WORK = 3  # seconds the robots' command takes
HOLD = 60  # what bounds each test's command: far beyond the bound


class Robots:
    """SSH servers whose commands take HOLD seconds, each behind a Link;
    ``started`` is set when a command began on every one of them."""

    def __init__(self, client_key, count: int = 2):
        self.running = threading.Semaphore(0)
        self.count = count
        self.servers = [sshserver.ssh_server(client_key, self.answer) for _ in range(count)]
        self.links = [Link(server.port) for server in self.servers]

    def answer(self, command: str):
        self.running.release()
        time.sleep(WORK)
        return b"done\n", 0

    def wait_running(self, count: int | None = None) -> None:
        for _ in range(self.count if count is None else count):
            assert self.running.acquire(timeout=60), "the command did not start on every robot"

    def fleet(self, tmp_path, **settings):
        lines = []
        for server, link in zip(self.servers, self.links):
            key = server.host_key
            lines.append(f"{hostkeys.entry('127.0.0.1', link.port)} {key.get_name()} {key.get_base64()}\n")
        hosts = {f"robot{i + 1}": {"address": "127.0.0.1", "ssh_port": link.port} for i, link in enumerate(self.links)}
        path = fleet(tmp_path, hosts, ssh_keepalive_interval=INTERVAL, ssh_keepalive_count_max=COUNT, **settings)
        (tmp_path / "known_hosts").write_text("".join(lines))
        return path

    def close(self) -> None:
        for item in (*self.links, *self.servers):
            item.close()


@pytest.fixture
def robots(client_key):
    made = Robots(client_key)
    yield made
    made.close()


def started(path, tmp_path, *argv, timeout: float):
    """``run`` in a thread: (the thread, a dict that gets 'result' and 'seconds')."""
    out: dict = {}

    def go():
        began = time.monotonic()
        try:
            out["result"] = run(path, tmp_path, *argv, timeout=timeout)
        finally:
            out["seconds"] = time.monotonic() - began

    thread = threading.Thread(target=go, daemon=True)
    thread.start()
    return thread, out


def test_a_frozen_link_fails_its_robot_in_bound_and_the_others_finish(robots, tmp_path):
    path = robots.fleet(tmp_path)
    argv = ("-c", PYINFRA, "-y", "inventories/robots.py", "exec", "--", "true")
    thread, out = started(path, tmp_path, *argv, timeout=HOLD)
    robots.wait_running()
    robots.links[0].freeze()
    frozen_at = time.monotonic()
    thread.join(HOLD + 5)
    result = out["result"]
    waited = time.monotonic() - frozen_at
    lines = [line for line in result.stderr.splitlines() if "robot1" in line and "link frozen" in line]
    assert len(lines) == 1, result.stderr[-3000:]
    assert f"127.0.0.1:{robots.links[0].port}" in lines[0]
    assert "ssh_keepalive_interval: 1, ssh_keepalive_count_max: 2" in lines[0]
    assert result.returncode == 1
    assert "[robot2] Success" in result.stderr, result.stderr[-3000:]
    assert waited < BOUND, f"ended {waited:.1f} s after the freeze"


def test_status_and_a_rollout_with_a_frozen_robot_return_in_bound_naming_it(robots, tmp_path):
    path = robots.fleet(tmp_path)
    thread, out = started(path, tmp_path, "-m", "robotfleet", "status", "inventories/robots.py", "--json", timeout=HOLD)
    robots.wait_running()
    robots.links[0].freeze()
    frozen_at = time.monotonic()
    thread.join(HOLD + 5)
    waited = time.monotonic() - frozen_at
    result = out["result"]
    rows = {row["host"]: row for row in json.loads(result.stdout)}
    assert rows["robot1"]["reachable"] is False, rows
    assert rows["robot1"]["error"].startswith(f"link frozen: no answer from 127.0.0.1:{robots.links[0].port}")
    assert rows["robot2"]["reachable"] is True and not rows["robot2"].get("error"), rows
    assert result.returncode == 3  # unreachable, none failed
    assert waited < BOUND, f"ended {waited:.1f} s after the freeze"

    # A rollout asks the fleet's status first: the frozen robot is skipped, named, and the rollout goes on.
    robots.links[0].thaw()
    argv = ("-m", "robotfleet", "rollout", "inventories/robots.py", "--dry")
    thread, out = started(path, tmp_path, *argv, timeout=HOLD)
    robots.wait_running()
    robots.links[0].freeze()
    frozen_at = time.monotonic()
    thread.join(HOLD + 5)
    waited = time.monotonic() - frozen_at
    said = [line for line in out["result"].stderr.splitlines() if "[robot1] unreachable: link frozen" in line]
    assert len(said) == 1, out["result"].stderr[-3000:]
    assert waited < BOUND + WORK, f"ended {waited:.1f} s after the freeze"


def test_enroll_over_a_frozen_link_ends_within_its_connect_timeout(robots, tmp_path):
    path = robots.fleet(tmp_path)
    robots.links[0].freeze()  # new connections too: nothing is ever delivered
    began = time.monotonic()
    result = run(path, tmp_path, "-m", "robotfleet", "enroll", "inventories/robots.py", "--yes", timeout=HOLD)
    assert time.monotonic() - began < 2 + 15  # ssh_connect_timeout: 2, and the command's own start
    said = [line for line in result.stderr.splitlines() if "robot1" in line]
    assert any("sent nothing within 2 s: a link that stalls" in line for line in said), result.stderr[-2000:]
