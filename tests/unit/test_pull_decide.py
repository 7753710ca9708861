"""What a pull robot does with a verified release (robotfleet/pull/robot/decide.py, pure)."""

import datetime

import pytest

from robotfleet.pull.protocol import record as records
from robotfleet.pull.protocol import waves
from robotfleet.pull.robot import decide as deciding

UTC = datetime.timezone.utc
PUBLISHED = datetime.datetime(2026, 11, 25, 10, 0, tzinfo=UTC)  # a Wednesday
ROBOTS = [f"robot{i}" for i in range(1, 11)]


def record(version=7, robots=ROBOTS, halt=False, **plan):
    made = records.build(
        version,
        PUBLISHED,
        PUBLISHED + datetime.timedelta(days=30),
        "a" * 40,
        "b" * 64,
        "inventories/robots.yaml",
        "c" * 64,
        robots,
        {},
        {},
        waves.parse_plan({"canary": "1", "waves": ["50%", "100%"], "pause": 600, "max_failed": "0", **plan}),
    )
    return made.halted(version, PUBLISHED, PUBLISHED + datetime.timedelta(days=30), "bad payload") if halt else made


def in_wave(index, version=7, robots=ROBOTS, **plan):
    made = record(version, robots, **plan)
    return next(r for r in robots if waves.wave_of(r, robots, version, made.rollout) == index)


def test_an_applied_release_is_up_to_date():
    assert deciding.decide(record(), "robot1", 7, None, PUBLISHED).result == "up-to-date"
    assert deciding.decide(record(), "robot1", 9, None, PUBLISHED).result == "up-to-date"


def test_the_canary_applies_at_once():
    canary = in_wave(0)
    assert deciding.decide(record(), canary, 6, None, PUBLISHED) == deciding.Decision(deciding.APPLY, None, 0)


def test_a_later_wave_waits_for_its_time_without_reading_reports():
    robot = in_wave(2)
    decision = deciding.decide(record(), robot, 6, None, PUBLISHED + datetime.timedelta(seconds=60))
    assert decision.result == "waiting" and decision.wave == 2 and decision.earlier == ()
    assert "waiting for wave 2 (opens at 2026-11-25T10:20:00Z)" in decision.reason


def test_an_open_later_wave_reads_the_earlier_waves_then_goes_or_stops():
    robot, late = in_wave(1), PUBLISHED + datetime.timedelta(seconds=700)
    asking = deciding.decide(record(), robot, 6, None, late)
    assert asking.result == "waiting" and set(asking.earlier) == {in_wave(0)}
    assert deciding.decide(record(), robot, 6, None, late, failed=0).result == deciding.APPLY
    stopped = deciding.decide(record(), robot, 6, None, late, failed=1)
    assert stopped.result == "stopped"  # not "halted": that is the word of the operator's signed halt
    assert stopped.reason == "wave 1 stopped by the failure budget: 1 robot(s) of the earlier waves failed (budget 0)"


def test_a_halt_stops_every_robot_that_has_not_applied():
    decision = deciding.decide(record(8, halt=True), "robot3", 6, None, PUBLISHED)
    assert decision.result == "halted" and decision.reason == "release 8 is a halt: bad payload"
    assert deciding.decide(record(8, halt=True), "robot3", 8, None, PUBLISHED).result == "up-to-date"


def test_a_release_not_for_this_robot_changes_nothing():
    decision = deciding.decide(record(robots=["robot1"]), "robot9", 6, None, PUBLISHED)
    assert decision == deciding.Decision("up-to-date", "release 7 is not for robot9")


def test_a_rolled_back_release_is_not_tried_again():
    canary = in_wave(0)
    attempted = {"version": 7, "result": "rolled-back", "tries": 1, "reason": "unhealthy"}
    decision = deciding.decide(record(), canary, 6, attempted, PUBLISHED)
    assert decision.result == "rolled-back"
    assert decision.reason == "release 7 failed here (unhealthy); waiting for a newer release"
    assert deciding.decide(record(8), in_wave(0, 8), 6, attempted, PUBLISHED).result == deciding.APPLY


@pytest.mark.parametrize("tries, expected", [(1, deciding.APPLY), (2, deciding.APPLY), (3, "failed")])
def test_a_failed_release_is_tried_again_a_few_times(tries, expected):
    attempted = {"version": 7, "result": "failed", "tries": tries, "reason": "fetch"}
    assert deciding.decide(record(), in_wave(0), 6, attempted, PUBLISHED).result == expected


def test_outside_the_maintenance_window_a_robot_waits_and_says_when():
    windows = [waves.parse_window("daily 01:00-03:00 UTC")]
    decision = deciding.decide(record(), in_wave(0), 6, None, PUBLISHED, windows)
    assert decision.result == "waiting"
    assert decision.reason == "outside the maintenance window; next at 2026-11-26T01:00:00Z"
    inside = PUBLISHED.replace(hour=1, minute=30) + datetime.timedelta(days=1)
    assert deciding.decide(record(), in_wave(0), 6, None, inside, windows).result == deciding.APPLY
