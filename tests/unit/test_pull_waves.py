"""Waves decided on the robot (robotfleet/pull/protocol/waves.py): ranking, wave
sizes, opening times, the failure budget, halts and maintenance windows."""

import datetime
import hashlib

import pytest

from robotfleet.pull.protocol import waves

UTC = datetime.timezone.utc
PUBLISHED = datetime.datetime(2026, 11, 25, 10, 0, tzinfo=UTC)  # a Wednesday
ROBOTS = [f"robot{i}" for i in range(1, 11)]


def plan(**raw):
    return waves.parse_plan({"canary": "1", "waves": ["50%", "100%"], "pause": 600, "max_failed": "0", **raw})


def test_robots_are_ranked_by_the_hash_of_name_and_version():
    expected = sorted(ROBOTS, key=lambda n: hashlib.sha256(f"{n}7".encode()).hexdigest())
    assert waves.rank(ROBOTS, 7) == expected
    assert waves.rank(ROBOTS, 8) != waves.rank(ROBOTS, 7)  # another release, another canary
    assert waves.rank(list(reversed(ROBOTS)), 7) == expected  # not the file's order


def test_canary_then_cumulative_shares():
    made = waves.waves(ROBOTS, 7, plan())
    assert [len(w) for w in made] == [1, 4, 5]
    assert sum(made, []) == waves.rank(ROBOTS, 7)
    assert [len(w) for w in waves.waves(ROBOTS, 7, plan(canary="20%", waves=["30%", "100%"]))] == [2, 1, 7]
    # a share rounds up, a wave that would be empty is dropped
    assert [len(w) for w in waves.waves(ROBOTS[:3], 7, plan(canary="1", waves=["10%", "100%"]))] == [1, 2]
    assert waves.waves([], 7, plan()) == []


def test_each_robot_knows_its_wave_and_the_robots_before_it():
    made = waves.waves(ROBOTS, 7, plan())
    last = made[2][0]
    assert waves.wave_of(last, ROBOTS, 7, plan()) == 2
    assert sorted(waves.earlier_robots(last, ROBOTS, 7, plan())) == sorted(made[0] + made[1])
    assert waves.earlier_robots(made[0][0], ROBOTS, 7, plan()) == []
    assert waves.wave_of("robot99", ROBOTS, 7, plan()) is None


def test_a_wave_opens_after_its_pauses():
    made = waves.waves(ROBOTS, 7, plan())
    second = made[1][0]
    early = waves.gate(second, ROBOTS, 7, plan(), PUBLISHED, PUBLISHED + datetime.timedelta(seconds=599), failed=0)
    assert not early.open and early.at == PUBLISHED + datetime.timedelta(seconds=600)
    assert early.why == "waiting for wave 1 (opens at 2026-11-25T10:10:00Z)"
    assert waves.gate(second, ROBOTS, 7, plan(), PUBLISHED, PUBLISHED + datetime.timedelta(seconds=600), 0).open
    assert waves.gate(made[0][0], ROBOTS, 7, plan(), PUBLISHED, PUBLISHED, 0).open


def test_the_failure_budget_of_the_earlier_waves_stops_the_next():
    second = waves.waves(ROBOTS, 7, plan())[1][0]
    later = PUBLISHED + datetime.timedelta(hours=1)
    stopped = waves.gate(second, ROBOTS, 7, plan(), PUBLISHED, later, failed=1)
    assert not stopped.open and stopped.at is None
    assert stopped.why == "wave 1 stopped by the failure budget: 1 robot(s) of the earlier waves failed (budget 0)"
    assert waves.gate(second, ROBOTS, 7, plan(max_failed="10%"), PUBLISHED, later, failed=1).open  # 10% of 10
    assert not waves.gate(second, ROBOTS, 7, plan(max_failed="10%"), PUBLISHED, later, failed=2).open


def test_a_halt_or_another_robots_release_does_not_open():
    first = waves.waves(ROBOTS, 7, plan())[0][0]
    halted = waves.gate(first, ROBOTS, 7, plan(), PUBLISHED, PUBLISHED, 0, halted=True)
    assert (halted.open, halted.why) == (False, "release 7 is halted")
    assert waves.gate("robot99", ROBOTS, 7, plan(), PUBLISHED, PUBLISHED, 0).why == "release 7 is not for robot99"


@pytest.mark.parametrize(
    "raw, says",
    [
        ({"waves": ["50%", "40%", "100%"]}, "rollout.waves[1]: shares are cumulative and must rise, got 40% after 50%"),
        ({"waves": ["3", "100%"]}, "rollout.waves[0]: expected a share of the robots like 50%, got '3'"),
        ({"waves": []}, "rollout.waves: expected a list of cumulative shares ending at 100%"),
        ({"pause": -1}, "rollout.pause: expected seconds between waves"),
        ({"pause": True}, "rollout.pause: expected seconds between waves"),
        (
            {"max_failed": "150%"},
            "rollout.max_failed: expected a number of robots or a percentage like 25%, got '150%'",
        ),
        ({"speed": 3}, "rollout: unknown field 'speed'"),
    ],
)
def test_a_bad_plan_is_one_line(raw, says):
    with pytest.raises(ValueError) as caught:
        plan(**raw)
    assert str(caught.value).startswith(says), str(caught.value)


def test_a_plan_is_written_as_it_was_read():
    raw = {"canary": "10%", "waves": ["25%", "100%"], "pause": 30, "max_failed": "1"}
    assert waves.parse_plan(raw).to_dict() == raw
    assert waves.parse_plan({}) == waves.Plan()


def at(day: int, hour: int, minute: int = 0, tz=UTC):
    """2026-11-23 is a Monday: day 0."""
    return datetime.datetime(2026, 11, 23 + day, hour, minute, tzinfo=tz)


def test_maintenance_windows_by_day_and_time():
    weekdays = [waves.parse_window("Mon-Fri 01:00-05:00 UTC")]
    assert waves.in_window(weekdays, at(0, 1))
    assert waves.in_window(weekdays, at(4, 4, 59))
    assert not waves.in_window(weekdays, at(4, 5))
    assert not waves.in_window(weekdays, at(5, 2))  # Saturday
    assert waves.in_window([], at(5, 2))  # no window: always


def test_a_window_past_midnight_belongs_to_the_day_it_starts():
    friday_night = [waves.parse_window("fri 22:00-02:00 utc")]
    assert waves.in_window(friday_night, at(4, 23))
    assert waves.in_window(friday_night, at(5, 1, 59))  # Saturday morning, still Friday's window
    assert not waves.in_window(friday_night, at(3, 23, 30))
    assert not waves.in_window(friday_night, at(4, 1))  # Friday morning is Thursday's


def test_local_windows_use_the_robots_time_zone():
    berlin = datetime.timezone(datetime.timedelta(hours=1))
    window = [waves.parse_window("daily 02:00-03:00")]
    assert waves.in_window(window, at(2, 1, 30), local=berlin)  # 02:30 in UTC+1
    assert not waves.in_window(window, at(2, 2, 30), local=berlin)


def test_lists_ranges_and_the_next_opening():
    weekend = [waves.parse_window("Sat,Sun 10:00-12:00 UTC"), waves.parse_window("Fri-Mon 23:00-23:30 UTC")]
    assert waves.in_window(weekend, at(6, 11))
    assert waves.in_window(weekend, at(0, 23, 10))  # Fri-Mon wraps through the weekend
    assert not waves.in_window(weekend, at(1, 23, 10))
    assert waves.next_window(weekend, at(1, 12)) == at(4, 23)
    assert waves.next_window(weekend, at(6, 11, 0)) == at(6, 11, 0)
    assert waves.next_window([], at(1, 12)) is None


@pytest.mark.parametrize(
    "text, says",
    [
        ("Mon-Fri 01:00", "maintenance window 'Mon-Fri 01:00': expected DAYS HH:MM-HH:MM [UTC]"),
        ("Mon-Fry 01:00-05:00", "maintenance window 'Mon-Fry 01:00-05:00': 'Mon-Fry' is not a day or a range of days"),
        ("daily 25:00-05:00", "maintenance window 'daily 25:00-05:00': 25:00 is not a time of day"),
        ("daily 01:00-01:00", "maintenance window 'daily 01:00-01:00': starts and ends at the same time"),
        ("Mon 01:00-02:00 CET", "maintenance window 'Mon 01:00-02:00 CET': expected DAYS HH:MM-HH:MM [UTC]"),
        (5, "maintenance window: expected text like 'Mon-Fri 01:00-05:00', got 5"),
    ],
)
def test_a_bad_window_is_one_line(text, says):
    with pytest.raises(ValueError) as caught:
        waves.parse_window(text)
    assert str(caught.value).startswith(says), str(caught.value)


def test_publish_prints_the_signed_plan_wave_by_wave():
    made = waves.waves(ROBOTS, 7, plan())
    lines = waves.describe(ROBOTS, 7, plan(), PUBLISHED, shown=3)
    assert lines[0].startswith("3 wave(s); wave k opens at publish + k x 600 s")
    assert "at most 0 robot(s) of the earlier waves failed (--max-failed 0)" in lines[0]
    assert lines[1] == f"  wave 0 (canary): 1 robot(s) from 2026-11-25T10:00:00Z: {made[0][0]}"
    assert lines[2] == f"  wave 1: 4 robot(s) from 2026-11-25T10:10:00Z: {', '.join(made[1][:3])} and 1 more"
    assert lines[3].startswith("  wave 2: 5 robot(s) from 2026-11-25T10:20:00Z: ")
    no_canary = waves.describe(ROBOTS[:2], 7, plan(canary="0", waves=["100%"], max_failed="50%"), PUBLISHED)
    assert no_canary[1] == f"  wave 0: 2 robot(s) from 2026-11-25T10:00:00Z: {', '.join(waves.rank(ROBOTS[:2], 7))}"
    assert "at most 1 robot(s)" in no_canary[0]
