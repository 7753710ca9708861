"""The page of status --html, pure parts (robotfleet/commands/statuspage.py):
a host's health, a report's age in words, the payload's release history,
a rollout's waves; tests/integration/test_status_page.py renders it in a browser."""

from __future__ import annotations

import datetime

from robotfleet import deploy_roles
from robotfleet.commands import rollout_plan, statuspage
from robotfleet.status_parts import state_of
from roles.payload import report


def test_a_host_s_health_from_its_row():
    assert state_of({"reachable": True}) == "healthy"
    assert state_of({"reachable": True, "drift": "runs p:0, not p:1"}) == "drifted"
    assert state_of({"reachable": True, "error": "unreadable payload status"}) == "failed"
    refused = "connection refused by 127.0.0.1:22 (no SSH server listens on port 22)"
    assert state_of({"reachable": False, "error": refused}) == "unreachable"
    assert state_of({"reachable": False, "error": "host key CHANGED for robot1"}) == "failed"
    pulled = {"reachable": "pull", "via": "report", "error": "failed: release 7"}
    assert state_of(pulled) == "failed"


def test_ages_in_words():
    assert [statuspage.age(s) for s in (-3, 42, 60, 3599, 3600, 3660, 50 * 3600, 72 * 3600)] == [
        "0 s",
        "42 s",
        "1 min",
        "59 min",
        "1 h",
        "1 h 1 min",
        "2 d 2 h",
        "3 d",
    ]


def test_the_payload_s_releases_newest_first():
    row = {
        "release": "r3",
        "release_state": "active",
        "deployed": "2026-11-25T10:00:00Z",
        "rolled_back_from": {"id": "r4", "reason": "unhealthy", "time": "2026-11-25T10:05:00Z"},
        "previous": "r2",
        "result": {"payloadctl": 1, "ok": False, "outcome": "rolled-back", "reason": "unhealthy"},
    }
    assert report.history(row) == [
        ("current", "r3 (active since 2026-11-25T10:00:00Z)"),
        ("rolled back from", "r4 at 2026-11-25T10:05:00Z: unhealthy"),
        ("previous", "r2"),
        ("last run", "rolled-back: unhealthy"),
    ]
    assert report.history({}) == []
    # a payloadctl that lists the releases kept on the robot: each of them, newest first
    row["releases"] = [
        {"id": "r4", "state": "failed", "created": "2026-11-25T10:04:00Z", "reason": "unhealthy"},
        {"id": "r3", "state": "active", "created": "2026-11-25T09:59:00Z", "activated": "2026-11-25T10:00:00Z"},
        {"id": "r2", "state": "active", "created": "2026-11-24T09:00:00Z"},
    ]
    assert report.history(row) == [
        ("failed", "r4 (failed, 2026-11-25T10:04:00Z): unhealthy"),
        ("current", "r3 (active, 2026-11-25T10:00:00Z)"),
        ("previous", "r2 (active, 2026-11-24T09:00:00Z)"),
        ("last run", "rolled-back: unhealthy"),
    ]


def test_a_rollout_s_waves_and_how_far_each_got():
    state = rollout_plan.new_state("k", "inv", [["a"], ["b", "c"], ["d"]], {}, 0)
    state = rollout_plan.record_wave(state, 0, ["a"], {}, {})
    state = rollout_plan.record_wave(state, 1, ["b"], {"c": "unhealthy"}, {})
    view = statuspage.rollout_view(state)
    assert (view["status"], view["current"]) == ("stopped", 2)
    assert [(w["done"], w["total"], w["percent"]) for w in view["waves"]] == [(1, 1, 100), (1, 2, 50), (0, 1, 0)]
    assert view["waves"][1]["hosts"] == [("b", "done", None), ("c", "failed", "unhealthy")]
    assert statuspage.rollout_view(None) is None


def test_a_pull_robot_s_report_age_is_as_of_the_page_s_time():
    taken = datetime.datetime(2026, 11, 25, 10, 30, tzinfo=datetime.timezone.utc)
    row = {"host": "r", "via": "report", "pull": "applied 3", "report": {"time": "2026-11-25T10:00:00Z"}}
    assert statuspage.pull_view(row, taken)["age"] == "30 min"
    assert statuspage.pull_view({"host": "r", "via": "report"}, taken)["age"] is None
    assert statuspage.pull_view({"host": "r"}, taken) is None


def test_every_value_is_escaped():
    row = {"host": "robot1", "reachable": True, "release": "<script>x</script>", "drift": "<b>"}
    page = statuspage.render([row], None, deploy_roles.roles(), 0)
    assert "<script>x" not in page and "&lt;script&gt;x&lt;/script&gt;" in page and "<b>" not in page
