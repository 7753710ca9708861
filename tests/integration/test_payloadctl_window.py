"""payloadctl's update window and its rollback as soon as Docker's verdict
is in, against the stand-in docker CLI (tests/integration/fakebin): the
health wait wakes on Docker's events (payloadctl/events.py), and `current`
is brought up in the apply's own process while the unit runs
(payloadctl/start.py).  On real Docker: tests/e2e/test_releases.py and
tests/e2e/test_faults_release.py; the figures: tests/bench/releases.py."""

import json
import os
import time

import pytest

from roles.payload.payloadctl import events, health
from tests.integration.payloadrobot import FAKEBIN


@pytest.fixture
def fake_docker(tmp_path, monkeypatch):
    """The stand-in docker first on PATH for code run in this process."""
    state = tmp_path / "state.json"
    state.write_text(json.dumps({"root": str(tmp_path), "images": {}, "containers": {}, "log": []}))
    monkeypatch.setenv("PATH", f"{FAKEBIN}:{os.environ['PATH']}")
    monkeypatch.setenv("FAKE_STATE", str(state))
    return state


def test_the_stream_asks_docker_for_the_projects_container_events_since_a_moment(fake_docker, tmp_path, monkeypatch):
    asked = tmp_path / "args.json"
    monkeypatch.setenv("FAKE_EVENTS_ARGS", str(asked))
    monkeypatch.setenv("FAKE_EVENTS", "0.2:health_status: unhealthy")
    with events.Events("robot-payload", since=1700000000.25) as stream:
        assert stream.wait(10)
    args = json.loads(asked.read_text())
    assert args[:3] == ["events", "--format", "{{.Action}}"]
    filters = [args[i + 1] for i, a in enumerate(args) if a == "--filter"]
    assert "type=container" in filters and "label=com.docker.compose.project=robot-payload" in filters
    assert {"event=die", "event=start", "event=health_status"} <= set(filters)
    assert args[args.index("--since") + 1] == "1700000000.250000"  # replayed from then: nothing missed


def test_a_wait_ends_when_docker_reports_and_not_before(fake_docker, monkeypatch):
    monkeypatch.setenv("FAKE_EVENTS", "0.5:die")
    monkeypatch.setenv("FAKE_EVENTS_HOLD", "30")
    with events.Events("robot-payload") as stream:
        started = time.monotonic()
        assert stream.wait(10) is True
        assert 0.3 < time.monotonic() - started < 3
        started = time.monotonic()
        assert stream.wait(0.4) is False  # nothing more: the whole pause
        assert time.monotonic() - started >= 0.35 and stream.streaming


def test_without_a_stream_the_wait_polls(fake_docker, monkeypatch):
    monkeypatch.setenv("FAKE_EVENTS", "")
    with events.Events("robot-payload") as stream:
        stream.wait(5)  # the stream ends at once: noticed, then polling
        started = time.monotonic()
        assert stream.wait(30) is False and not stream.streaming
        assert time.monotonic() - started < events.POLL + 1


def unhealthy_release(fake_docker):
    """A container whose health check Docker calls unhealthy at the stand-in's
    third look (the first two say starting)."""
    state = json.loads(fake_docker.read_text())
    state["images"]["reg/ros/payload:bad"] = {"id": "sha256:bad", "behaviour": "unhealthy", "present": True}
    state["containers"] = {
        "robot-payload-payload-1": {
            "image": "reg/ros/payload:bad",
            "name": "robot-payload-payload-1",
            "service": "payload",
            "policy": "no",
        }
    }
    fake_docker.write_text(json.dumps(state))


def test_the_health_wait_acts_on_dockers_events_not_on_a_timer(fake_docker, monkeypatch):
    """Each event makes it look again at once: the verdict comes with the
    events, not after a pause between looks (it used to look every 0.5 s)."""
    unhealthy_release(fake_docker)
    # Six seconds apart: two events read in one burst wake one look, and the
    # stand-in turns unhealthy at its third look, not with the event (under
    # CI's load a look can outlast a shorter gap).
    monkeypatch.setenv("FAKE_EVENTS", "0.05:health_status: starting,6:health_status: unhealthy")
    monkeypatch.setenv("FAKE_EVENTS_HOLD", "30")
    monkeypatch.setattr(health, "LOOK", 30.0)  # a look on the timer would take 30 s: only the events can end it sooner
    started = time.monotonic()
    ok, why = health.wait_healthy("robot-payload", 120, 5)
    took = time.monotonic() - started
    assert not ok and "robot-payload-payload-1 is unhealthy" in why
    assert took < 20, took  # three looks, two events, no pause: about 6 s, not the timer's 30

    monkeypatch.setattr(health, "LOOK", 2.0)

    unhealthy_release(fake_docker)  # a stream that says nothing: a look every health.LOOK s all the same
    monkeypatch.setenv("FAKE_EVENTS", "")
    started = time.monotonic()
    ok, why = health.wait_healthy("robot-payload", 60, 5)
    assert not ok and 2 * health.LOOK <= time.monotonic() - started < 2 * health.LOOK + 3


def test_while_the_unit_runs_the_release_is_brought_up_here_else_through_the_unit(robot):
    robot.image("reg/ros/payload:1.1")
    assert robot.apply("reg/ros/payload:1.1", run_id="run-1").returncode == 0
    log = robot.state()["log"]
    assert not [line for line in log if line.startswith(("systemctl reload", "systemctl restart", "systemctl start"))]
    assert any(" up -d --remove-orphans" in line for line in log)
    state = robot.state()
    state["unit_active"] = False  # stopped (by hand, or it failed)
    state["log"] = []
    robot.save(state)
    robot.image("reg/ros/payload:1.2")
    assert robot.apply("reg/ros/payload:1.2", run_id="run-2").returncode == 0
    assert "systemctl restart robot-payload.service" in robot.state()["log"]
    assert robot.state()["unit_active"] is True
