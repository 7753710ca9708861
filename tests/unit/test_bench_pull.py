"""tests/bench/pull.py's arithmetic: what a 10,000-robot fleet asks of the
git server per hour, from one robot's measured check (pure)."""

import pytest

from tests.bench import pull

IDLE = {
    "without a report push": {"seconds": 1.0, "cpu": 0.2, "sent": 4000, "received": 5000, "requests": 1},
    "with a report push": {"seconds": 2.0, "cpu": 0.3, "sent": 9000, "received": 6000, "requests": 2},
}


def test_checks_pushes_requests_and_bytes_per_hour_from_the_measured_check():
    row = pull.fleet_per_hour(IDLE, 900, 300, heartbeat=3600, robots_measured=4)
    checks = 10_000 * 3600 / (900 + 150 + 1.0)
    pushes = 10_000 * 3600 / (3600 + 900 + 150)
    assert row["checks_per_hour"] == round(checks) == 34_253
    assert row["report_pushes_per_hour"] == round(pushes) == 7_742
    assert row["git_requests_per_hour"] == round(checks * 1 + pushes * 1)
    push_extra = (15_000 - 9_000) + 64 * (10_000 - 4)  # the advertisement grows with the fleet's report refs
    assert row["bytes_per_hour"] == round(checks * 9_000 + pushes * push_extra)
    assert row["megabits_per_second"] == pytest.approx(row["bytes_per_hour"] * 8 / 3600 / 1e6, abs=0.01)


def test_a_push_at_most_every_check():
    row = pull.fleet_per_hour(IDLE, 30, 0, heartbeat=0, robots_measured=1, fleet=100)
    assert row["report_pushes_per_hour"] == row["checks_per_hour"]


def test_the_journal_line_with_and_without_its_request_count():
    new = (
        "robot-pull: up-to-date (release 3): nothing new; 0.9 s, 0.22 s CPU, sent 4108 B, received 4936 B "
        "in 1 requests; report unchanged"
    )
    old = "robot-pull: waiting (release 3): w; 1.0 s, 0.22 s CPU, sent 4108 B, received 4936 B; report unchanged"
    assert pull.LINE.match(new)["requests"] == "1" and pull.LINE.match(new)["received"] == "4936"
    assert pull.LINE.match(old)["requests"] is None and pull.LINE.match(old)["report"] == "report unchanged"
