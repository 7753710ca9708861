"""The git server load generator's schedule and summary (tests/bench/git_load.py): pure, bounded."""

from tests.bench import git_load
from tests.bench.gitolite_fleet import NAME

ROBOTS = [NAME.format(i) for i in range(2_000)]


def test_the_schedule_is_a_steady_fleet_s_checks_and_heartbeat_pushes():
    events = git_load.schedule(ROBOTS, 900, 300, 3600, minutes=60, limit=10**6)
    assert [e[0] for e in events] == sorted(e[0] for e in events) and events[-1][0] <= 3600
    # each robot checks every 900 + 150 s on average, and pushes once an hour
    assert 2_000 * 3600 / 1050 * 0.9 < len(events) < 2_000 * 3600 / 1050 * 1.1
    pushes = sum(e[2] for e in events)
    # at the first check a heartbeat after the last push: between docs/explanations/pull.md's bound
    # N*3600/(heartbeat + interval + jitter/2) and one an hour
    assert 2_000 * 3600 / 4650 * 0.95 < pushes <= 2_000, pushes
    one = [e for e in events if e[1] == ROBOTS[7]]
    gaps = [b[0] - a[0] for a, b in zip(one, one[1:])]
    assert all(900 <= gap <= 1200 for gap in gaps)


def test_the_schedule_is_bounded_in_count_and_time():
    assert len(git_load.schedule(ROBOTS, 900, 300, 3600, minutes=60, limit=100)) == 100
    assert max(e[0] for e in git_load.schedule(ROBOTS, 900, 300, 3600, minutes=5, limit=10**6)) <= 300
    assert git_load.schedule(ROBOTS, 900, 300, 3600, 5, 10**6) == git_load.schedule(ROBOTS, 900, 300, 3600, 5, 10**6)


def _row(at: float, lag: float, seconds: float, ok=True) -> dict:
    return {
        "at": at,
        "lag": lag,
        "seconds": seconds,
        "ok": ok,
        "push": at % 2 == 0,
        "requests": 1 + (at % 2 == 0),
        "bytes": 9000,
    }


def test_the_summary_shows_a_queue_as_lag_growing_from_the_first_third_to_the_last():
    steady = git_load.summary([_row(t, 0.01, 0.2) for t in range(90)], 90.0, 9.0, 18.0, 2)
    assert steady["lag p50/p95 first third"] == steady["lag p50/p95 last third"] == [0.01, 0.01]
    assert steady["checks per second"] == 1.0 and steady["sessions per second"] == 1.5
    assert steady["server CPU cores"] == 0.1 and steady["server CPU share of the machine"] == 0.05
    assert steady["server CPU ms per session"] == round(9000 / 135, 1)
    assert steady["bytes per hour"] == 90 * 9000 * 40 and steady["failed"] == 0
    queue = git_load.summary([_row(t, t / 10, 0.2 + t / 100) for t in range(90)], 90.0, 9.0, 18.0, 2)
    assert queue["lag p50/p95 last third"][0] > 4 * queue["lag p50/p95 first third"][0]
    assert queue["duration p50/p95 last third"][0] > queue["duration p50/p95 first third"][0]
    failed = git_load.summary([_row(0, 0, 1, ok="reports: DENIED")], 1.0, 0.0, 0.0, 2)
    assert failed["failed"] == 1 and failed["first failure"] == ["reports: DENIED"]


def test_the_schedule_opens_in_the_steady_state_pushes_included():
    """A 10-minute replay pushes at the fleet's steady rate: N / (heartbeat +
    the wait for the next check, ~529 s at 900 + U(0, 300)) a second."""
    events = git_load.schedule(ROBOTS, 900, 300, 3600, minutes=10, limit=10**6)
    steady = 2_000 * 600 / (3600 + 529)
    assert 0.85 * steady < sum(e[2] for e in events) < 1.15 * steady
    assert 0.9 * 2_000 * 600 / 1050 < len(events) < 1.1 * 2_000 * 600 / 1050
    assert min(e[0] for e in events) >= 0
