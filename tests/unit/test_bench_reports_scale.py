"""The reports benchmark's load generator schedule (tests/bench/reports_scale.py): pure, bounded."""

from tests.bench import reports_scale

ROBOTS = [reports_scale.NAME.format(i) for i in range(2_000)]


def test_the_schedule_is_a_steady_fleet_s_checks_and_heartbeat_pushes():
    events = reports_scale.schedule(ROBOTS, 900, 300, 3600, minutes=60, limit=10**6)
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
    assert len(reports_scale.schedule(ROBOTS, 900, 300, 3600, minutes=60, limit=100)) == 100
    assert max(e[0] for e in reports_scale.schedule(ROBOTS, 900, 300, 3600, minutes=5, limit=10**6)) <= 300
    assert reports_scale.schedule(ROBOTS, 900, 300, 3600, 5, 10**6) == reports_scale.schedule(ROBOTS, 900, 300, 3600,
                                                                                                5, 10**6)
