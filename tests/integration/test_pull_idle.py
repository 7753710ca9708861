"""What a pull check that finds nothing new costs (robotfleet/pull/robot/agent.py):
no roles' status process (what the last read
found, until a path the roles watch changes or the heartbeat is due), no
report push (until the report says something new or the heartbeat is due).
The agent against a real TUF repository and git remote (file://), with a
release whose converge is tests/integration/test_pull_agent.py's stub,
which logs each time it runs."""

from __future__ import annotations

import os
import shlex
import subprocess
import sys
import time

import pytest

import robotfleet
from robotfleet.pull.protocol import agent_files
from robotfleet.pull.robot import agent_state
from tests.integration.pullworld import World

# robot-pull.service's python code in the units the releases of 2026-11-28 to
# issue 53 wrote (python -S -c, robotfleet/pull/start.py): such a unit stays on
# a robot until the next release's converge writes the unit again, and starts
# the new tree meanwhile.  Frozen: it is on robots.
FIELD_START_CODE = (
    'import os, sys; os.path.exists("robotfleet/pull/start.py") or os.execv(sys.executable, '
    '[sys.executable, "-m", "robotfleet.pull.agent"] + sys.argv[1:]); '
    "from robotfleet.pull.start import main; sys.exit(main())"
)


@pytest.fixture
def world(tmp_path, monkeypatch):
    made = World(tmp_path)
    made.runs = tmp_path / "converge.log"
    monkeypatch.setenv("STUB_LOG", str(made.runs))
    made.release(1)
    made.wake()  # applied
    made.wake()  # up-to-date: said once
    made.runs.write_text("")
    return made


def age_state(world, seconds: float) -> None:
    """The last status read and report push, ``seconds`` earlier."""
    state = agent_state.load_state(world.state)
    state["status"]["at"] -= seconds
    state["reported"]["at"] -= seconds
    agent_state.save_state(world.state, state)


def test_an_idle_check_runs_no_status_process_and_pushes_nothing(world):
    report, outcome, sent = world.wake()
    assert (outcome.result, sent) == ("up-to-date", "report unchanged")
    assert world.runs.read_text() == ""
    assert report["status"]["release"] == "r-applied" and report["status_time"]


def test_a_watched_path_that_changed_reads_the_status_again(world, tmp_path, monkeypatch):
    payload = tmp_path / "payload"
    payload.mkdir()
    monkeypatch.setenv("STUB_WATCH", str(payload))
    age_state(world, 3600 * 2)  # the heartbeat: a read that learns what to watch
    world.wake()
    world.runs.write_text("")
    monkeypatch.setenv("STUB_HEALTH", "unhealthy")
    report, _, sent = world.wake()
    assert world.runs.read_text() == "" and report["status"]["health"] == "healthy" and sent == "report unchanged"
    (payload / "last-result.json").write_text("{}")  # what payloadctl renames into its directory
    report, _, sent = world.wake()
    assert world.runs.read_text() == "status\n"
    assert report["status"]["health"] == "unhealthy" and sent == "report sent"


def test_the_heartbeat_reads_the_status_and_pushes_the_report(world):
    age_state(world, world.config.heartbeat - 60)
    _, _, sent = world.wake()
    assert world.runs.read_text() == "" and sent == "report unchanged"
    age_state(world, 61)
    before = time.time()
    _, _, sent = world.wake()
    assert world.runs.read_text() == "status\n" and sent == "report sent"
    assert agent_state.load_state(world.state)["reported"]["at"] >= before


def test_a_release_to_try_again_is_verified_in_full_before_it_is_applied(world):
    world.release(2)
    _, outcome, _ = world.wake("failed")
    assert outcome.result == "failed"
    _, outcome, _ = world.wake()  # the same repository, verified again, then downloaded
    assert outcome.result == "applied"
    assert agent_state.load_state(world.state)["applied"]["version"] == 2


def test_a_check_removes_the_bytecode_directory_earlier_releases_kept(world, tmp_path):
    """Earlier releases' units named a bytecode directory in the agent's
    state directory (ROBOT_PULL_PYCACHE): a check removes what they left,
    even run by such a unit, and writes no bytecode anywhere."""
    config = tmp_path / "agent.json"
    config.write_text(world.config.to_json())
    left = world.state / "pycache" / ("ab" * 32) / "robotfleet"
    left.mkdir(parents=True)
    (left / "__init__.cpython-311.pyc").write_bytes(b"\0")
    env = dict(os.environ, PYTHONDONTWRITEBYTECODE="1", ROBOT_PULL_PYCACHE=str(world.state / "pycache"))
    done = subprocess.run(
        agent_files.start_command(sys.executable, str(config)), capture_output=True, text=True, env=env
    )
    assert done.returncode == 0 and "robot-pull: up-to-date" in done.stdout, done.stderr
    assert not (world.state / "pycache").exists()
    assert not list((robotfleet.CHECKOUT / "robotfleet" / "pull" / "robot").glob("__pycache__/transport.*"))
    assert "PYCACHE" not in agent_files.service_unit()


def test_the_unit_runs_the_agent_s_entry_point_and_a_unit_of_the_python_s_start_does_too(world, tmp_path):
    """robot-pull.service runs ``python -m robotfleet.pull.agent``, the
    entry point every release keeps; a unit of the releases that started
    ``python -S -c`` (FIELD_START_CODE) finds no robotfleet/pull/start.py in
    this tree and runs the same entry point, with site."""
    unit = agent_files.service_unit()
    exec_start = next(line for line in unit.splitlines() if line.startswith("ExecStart="))
    assert shlex.split(exec_start.removeprefix("ExecStart=")) == agent_files.start_command()
    assert "WorkingDirectory=/var/lib/robot-pull/code/current" in unit  # where FIELD_START_CODE looks
    assert not (robotfleet.CHECKOUT / "robotfleet" / "pull" / "start.py").exists()
    config = tmp_path / "agent.json"
    config.write_text(world.config.to_json())
    field = [sys.executable, "-S", "-c", FIELD_START_CODE, "--config", str(config)]
    for command in (agent_files.start_command(sys.executable, str(config)), field):
        env = dict(os.environ, PYTHONPATH=str(robotfleet.CHECKOUT), PYTHONDONTWRITEBYTECODE="1")
        done = subprocess.run(command, cwd=robotfleet.CHECKOUT, env=env, capture_output=True, text=True)
        assert done.returncode == 0 and "robot-pull: up-to-date" in done.stdout, done.stderr
