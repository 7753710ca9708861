"""The idle check in robot-pull.service's own process (robotfleet/pull/robot/idle.py):
``python -m robotfleet.pull.agent`` as the unit runs it (its imports counted
under ``python -S``: ``site`` and this venv's editable install are not the
agent's), against a real
TUF repository served over HTTPS on 127.0.0.1 (a static copy and git's smart
HTTP, tests/integration/httpsgit.py, as test_pull_idle_probe.py serves it)
and over SSH (git's upload-pack behind paramiko's server, tests/integration/gitssh.py).
A check that finds nothing new ends before the agent is imported, and says
and leaves what the full wake would; anything changed and the full wake runs,
without asking the server twice."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from robotfleet.pull.protocol import agent_files
from robotfleet.pull.robot import idle, probe, transport
from tests.integration import gitssh
from tests.integration.pullworld import World, https_world, serve_static

ROOT = Path(__file__).resolve().parents[2]
# What an idle check must not import: the agent's full path and what it brings.
HEAVY = {"pyinfra", "tuf", "securesystemslib", "yaml", "jinja2", "dataclasses", "pathlib", "subprocess", "tempfile"}


@pytest.fixture(scope="module")
def tls(tmp_path_factory):
    from tests.integration import httpsgit

    return httpsgit.make_ca(tmp_path_factory.mktemp("tls"))


@pytest.fixture(params=["static", "smart"])
def robot(request, tmp_path, tls):
    world = https_world(tmp_path, tls, request.param == "smart")
    world.config_file = tmp_path / "agent.json"
    world.config_file.write_text(world.config.to_json())
    world.runs = tmp_path / "converge.log"
    world.watched = tmp_path / "watched.conf"  # a path the roles' status reads (the stub's STUB_WATCH)
    world.watched.write_text("a")
    world.count = lambda: world.server.requests
    yield world
    world.server.close()


def check(world, *flags: str) -> tuple[str, set[str], int]:
    """One wake as the unit runs it: its journal line, the modules it
    imported, and the requests the server answered meanwhile."""
    env = dict(
        os.environ,
        PYTHONPATH=str(ROOT),
        PYTHONDONTWRITEBYTECODE="1",
        STUB="applied",
        STUB_LOG=str(world.runs),
        STUB_WATCH=str(world.watched),
    )
    before = world.count()
    done = subprocess.run(
        [
            sys.executable,
            "-X",
            "importtime",
            *flags,
            "-m",
            "robotfleet.pull.agent",
            "--config",
            str(world.config_file),
        ],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stdout + done.stderr[-2000:]
    modules = {
        line.rsplit("|", 1)[1].strip() for line in done.stderr.splitlines() if line.startswith("import time:")
    } - {"imported package"}
    lines = [line for line in done.stdout.splitlines() if line.startswith("robot-pull: ")]
    return lines[-1], modules, world.count() - before


def settled(world) -> str:
    """Applied, then one full idle wake (a static copy's first probe learns
    its validators; the wake leaves the idle memo); that wake's line."""
    line, _, _ = check(world)
    assert line.startswith("robot-pull: applied (release 1)"), line
    line, modules, _ = check(world)
    assert "robotfleet.pull.robot.agent" in modules, "the second wake was already the idle one"
    assert (world.state / idle.MEMO).is_file()
    world.runs.write_text("")
    return line


def words(line: str) -> tuple[str, str]:
    """A journal line without its figures: (the outcome, what the report did)."""
    head, _, rest = line.partition("; ")
    return head, rest.rsplit("; ", 1)[1]


def test_an_idle_check_imports_none_of_the_agent_s_heavy_modules(robot):
    settled(robot)
    (robot.state / idle.MEMO).unlink()
    full, modules, _ = check(robot)  # the same check by the full wake, which leaves the memo again
    assert "robotfleet.pull.robot.agent" in modules
    line, modules, requests = check(robot, "-S")
    assert modules & HEAVY == set(), sorted(modules & HEAVY)
    assert "ssl" in modules  # its TLS is the ssl module's (robotfleet/pull/robot/https_request.py)
    assert "robotfleet.pull.robot.agent" not in modules
    assert words(line) == words(full) == ("robot-pull: up-to-date (release 1)", "report unchanged")
    assert requests == 1 and " in 1 requests;" in line


def test_an_idle_check_leaves_what_the_full_wake_leaves(robot):
    settled(robot)
    state = (robot.state / "agent-state.json").read_bytes()
    reports = subprocess.run(
        ["git", "-C", str(robot.bare), "rev-parse", "refs/reports/robot1"], capture_output=True, text=True
    ).stdout
    trusted = json.loads((robot.state / "trust.json").read_text())
    time.sleep(1.1)  # the trusted time has whole seconds
    check(robot)
    now = json.loads((robot.state / "trust.json").read_text())
    assert now["time"] > trusted["time"] and {**now, "time": 0} == {**trusted, "time": 0}
    assert (robot.state / "agent-state.json").read_bytes() == state
    assert robot.runs.read_text() == ""  # no converge, no status read
    assert (
        subprocess.run(
            ["git", "-C", str(robot.bare), "rev-parse", "refs/reports/robot1"], capture_output=True, text=True
        ).stdout
        == reports
    )


def test_a_new_release_goes_to_the_full_wake_which_does_not_ask_again(robot):
    settled(robot)
    robot.release(2)
    serve_static(robot)
    os.utime(robot.bare / "info" / "refs", (time.time() - 90, time.time() - 90))  # later than the last one's
    line, modules, requests = check(robot)
    assert line.startswith("robot-pull: applied (release 2)"), line
    # the server answered what the wake counted (all but its report's push, which went elsewhere):
    # the idle check's probe was handed over, not asked twice
    report = json.loads(
        subprocess.run(
            ["git", "-C", str(robot.bare), "show", "refs/reports/robot1:report.json"], capture_output=True, check=True
        ).stdout
    )
    exchanges = report["check"]["exchanges"]
    assert [e["what"] for e in exchanges][0] == "probe"
    assert requests == sum(e["requests"] for e in exchanges if e["what"] != "report"), (exchanges, requests)
    assert words(check(robot)[0]) == ("robot-pull: up-to-date (release 2)", "report sent")  # full, as after any apply
    line, modules, requests = check(robot)
    assert words(line) == ("robot-pull: up-to-date (release 2)", "report unchanged")
    assert "robotfleet.pull.robot.agent" not in modules and requests == 1


def test_a_changed_key_sends_the_check_to_the_full_wake_and_its_report_is_sent(robot):
    settled(robot)
    key = robot.etc / "id_ed25519.pub"
    key.write_text(
        "ssh-ed25519 AAAAC3NzaC1lZDI1NTE5AAAAIBm0f0mPAKu8JQrhvXYlGQbWqZLhGJ7+hNYRqoAPeOrK robot-pull@robot1\n"
    )
    line, modules, _ = check(robot, "-S")  # the full wake, under -S, adds the site-packages itself (idle.leave)
    assert words(line) == ("robot-pull: up-to-date (release 1)", "report sent") and "tuf" not in modules
    assert "robotfleet.pull.robot.agent" in modules


@pytest.mark.parametrize("change", ["config", "heartbeat", "watched", "trust"])
def test_anything_the_memo_does_not_hold_sends_the_check_to_the_full_wake(robot, change):
    settled(robot)
    memo_file = robot.state / idle.MEMO
    if change == "config":
        robot.config_file.write_text(
            robot.config_file.read_text().replace('"fetch_timeout": 300', '"fetch_timeout": 299')
        )
    elif change == "heartbeat":  # the memo's limit passed (the heartbeat, or the metadata's expiry)
        memo = json.loads(memo_file.read_text())
        memo["until"] = time.time() - 1
        memo_file.write_text(json.dumps(memo))
    elif change == "watched":
        robot.watched.write_text("bb")
    else:
        trust = json.loads((robot.state / "trust.json").read_text())
        (robot.state / "trust.json").write_text(json.dumps({**trust, "version": trust["version"] + 1}))
    _, modules, _ = check(robot)
    assert "robotfleet.pull.robot.agent" in modules, change
    if change == "watched":  # and the full wake read the roles' status again
        assert robot.runs.read_text() != ""


def test_a_memo_that_cannot_be_written_costs_the_shortcut_not_the_check(robot):
    """The memo only saves work: where it cannot be removed or written (here
    its name is taken by a directory, as a full disk or a broken state file
    would stop the write) every check is the full wake, and says so."""
    settled(robot)
    memo = robot.state / idle.MEMO
    memo.unlink()
    memo.mkdir()
    for _ in range(2):
        line, modules, _ = check(robot)
        assert words(line) == ("robot-pull: up-to-date (release 1)", "report unchanged"), line
        assert "robotfleet.pull.robot.agent" in modules
    assert memo.is_dir() and not any(memo.iterdir())


# -- over SSH -------------------------------------------------------------------


@pytest.fixture
def over_ssh(tmp_path):
    """A robot whose fleet remote is git over SSH, releases and reports (gitolite's way)."""
    world = World(tmp_path)
    world.server = gitssh.GitSSHServer(world.base, gitssh.client_key(world.etc))
    (world.etc / "known_hosts").write_text(world.server.known_hosts(transport.HOST_KEY_ALIAS))
    world.config = agent_files.Config(**{**world.config.__dict__, "remote": world.server.url("fleet.git")})
    world.release(1)
    world.config_file = tmp_path / "agent.json"
    world.config_file.write_text(world.config.to_json())
    world.runs = tmp_path / "converge.log"
    world.watched = tmp_path / "watched.conf"
    world.watched.write_text("a")
    world.count = lambda: world.server.connections
    yield world
    world.server.close()


def figures(line: str) -> str:
    """A journal line's figures without their numbers ("s, s CPU, sent B, received B in requests")."""
    return " ".join(word for word in line.split("; ")[1].split() if not word[0].isdigit())


def git_out(repo, *args: str) -> str:
    return subprocess.run(["git", "-C", str(repo), *args], capture_output=True, text=True, check=True).stdout


def test_an_idle_check_over_ssh_is_one_session_without_the_agent(over_ssh):
    robot = over_ssh
    settled(robot)
    (robot.state / idle.MEMO).unlink()
    full, modules, _ = check(robot)
    assert "robotfleet.pull.robot.agent" in modules
    robot.server.commands[:] = []
    line, modules, connections = check(robot, "-S")
    # subprocess (git, ssh) it cannot do without; nothing of the agent's full path
    assert modules & (HEAVY - {"subprocess"}) == set(), sorted(modules & HEAVY)
    assert "robotfleet.pull.robot.agent" not in modules
    assert words(line) == words(full) == ("robot-pull: up-to-date (release 1)", "report unchanged")
    assert connections == 1 and robot.server.commands == ["ls-refs"]
    # the full wake's figures, counted the same way: ssh's own count of one session
    assert figures(line) == figures(full) == "s, s CPU, sent B, received B in requests", (line, full)
    assert " in 1 requests;" in line and " in 1 requests;" in full
    assert " sent 0 B" not in line and " received 0 B" not in line


def test_an_idle_check_over_ssh_leaves_what_the_full_wake_leaves(over_ssh):
    robot = over_ssh
    settled(robot)
    names = ("agent-state.json", "verified.json", f"releases/.git/{probe.MEMO}")
    kept = {name: (robot.state / name).read_bytes() for name in names}
    reports = git_out(robot.bare, "rev-parse", "refs/reports/robot1")
    trusted = json.loads((robot.state / "trust.json").read_text())
    time.sleep(1.1)  # the trusted time has whole seconds
    line, modules, _ = check(robot)
    assert "robotfleet.pull.robot.agent" not in modules
    now = json.loads((robot.state / "trust.json").read_text())
    assert now["time"] > trusted["time"] and {**now, "time": 0} == {**trusted, "time": 0}
    assert {name: (robot.state / name).read_bytes() for name in names} == kept
    assert robot.runs.read_text() == ""  # no converge, no status read
    assert git_out(robot.bare, "rev-parse", "refs/reports/robot1") == reports
    assert "robotfleet.pull.robot.agent" not in check(robot)[1]  # the memo stands for the next check too


def test_a_new_release_over_ssh_goes_to_the_full_wake_which_does_not_ask_again(over_ssh):
    robot = over_ssh
    settled(robot)
    robot.release(2)
    robot.server.sessions[:], robot.server.commands[:] = [], []
    line, modules, _ = check(robot)
    assert line.startswith("robot-pull: applied (release 2)"), line
    assert "robotfleet.pull.robot.agent" in modules
    # the idle check's ls-refs, then the fetch's own: the probe was handed over, not asked twice
    assert robot.server.commands[:3] == ["ls-refs", "ls-refs", "fetch"], robot.server.commands
    report = json.loads(git_out(robot.bare, "show", "refs/reports/robot1:report.json"))
    exchanges = report["check"]["exchanges"]
    assert [e["what"] for e in exchanges][:2] == ["probe", "fetch"] and exchanges[0]["received"] > 0
    reads = robot.server.sessions.count("git-upload-pack")
    assert reads == sum(e["requests"] for e in exchanges), (exchanges, robot.server.sessions)
    assert words(check(robot)[0]) == ("robot-pull: up-to-date (release 2)", "report sent")  # full, as after any apply
    line, modules, connections = check(robot)
    assert words(line) == ("robot-pull: up-to-date (release 2)", "report unchanged")
    assert "robotfleet.pull.robot.agent" not in modules and connections == 1


def test_a_new_pin_in_known_hosts_sends_the_check_to_the_full_wake(over_ssh):
    robot = over_ssh
    settled(robot)
    pinned = robot.etc / "known_hosts"
    pinned.write_text("# the git server's keys, pinned again\n" + pinned.read_text())
    line, modules, _ = check(robot)
    assert "robotfleet.pull.robot.agent" in modules
    assert words(line) == ("robot-pull: up-to-date (release 1)", "report unchanged"), line
    assert "robotfleet.pull.robot.agent" not in check(robot)[1]  # which left the memo again


def test_a_git_server_with_another_host_key_fails_the_full_wake_asked_once(over_ssh, tmp_path):
    """A reinstalled git server (or another in its place): the idle check's
    probe fails on the pinned host key; the full wake is handed that
    failure and says it, without connecting for the releases again."""
    import paramiko

    robot = over_ssh
    settled(robot)
    other = tmp_path / "other_host_key"
    subprocess.run(["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-f", str(other)], check=True)
    robot.server.host_key = paramiko.Ed25519Key.from_private_key_file(str(other))
    line, modules, connections = check(robot)
    assert "robotfleet.pull.robot.agent" in modules
    assert line.startswith("robot-pull: failed (release 1): fetch: probe: "), line
    assert "REMOTE HOST IDENTIFICATION HAS CHANGED" in line.split(";")[0] and "report not sent" in line
    # the idle check's probe and the report's push, as the wake counted them: no second probe
    assert connections == 2 and " in 2 requests;" in line, line
    assert not (robot.state / idle.MEMO).exists()


def test_an_enrollment_key_keeps_every_ssh_check_the_full_wake_until_it_is_retired(over_ssh):
    """While the robot holds a bundle's enrollment key (the server knows
    only that one yet), every check is the full wake: only it retires the
    key once the server takes the robot's own."""
    import paramiko

    robot = over_ssh
    enroll = robot.etc / "enroll_ed25519"
    subprocess.run(["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-f", str(enroll)], check=True)
    own, robot.server.client_key = robot.server.client_key, paramiko.Ed25519Key.from_private_key_file(str(enroll))
    for _ in range(3):
        line, modules, _ = check(robot)
        assert "robotfleet.pull.robot.agent" in modules and "retired" not in line, line
    assert not (robot.state / idle.MEMO).exists()
    robot.server.client_key = own  # robotfleet pull-enroll registered the robot's own key
    line, modules, _ = check(robot)
    assert "robotfleet.pull.robot.agent" in modules and "the enrollment key is retired" in line, line
    assert not enroll.exists()
    line, modules, _ = check(robot)  # the wake that retired it said more than an idle one: no memo yet
    assert "robotfleet.pull.robot.agent" in modules and words(line)[1] == "report unchanged", line
    assert "robotfleet.pull.robot.agent" not in check(robot)[1]
