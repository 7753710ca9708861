"""tests/bench/pull.py's arithmetic: what a 10,000-robot fleet asks of the
git server per hour, from one robot's measured check (pure)."""

import pytest

from tests.bench import prefetch, pull

IDLE = {
    "without a report push": {"seconds": 1.0, "cpu": 0.2, "sent": 4000, "received": 5000, "requests": 1},
    "with a report push": {"seconds": 2.0, "cpu": 0.3, "sent": 9000, "received": 6000, "requests": 2},
}


def test_checks_pushes_requests_and_bytes_per_hour_from_the_measured_check():
    row = pull.fleet_per_hour(IDLE, 900, 300, heartbeat=3600, robots_measured=4)
    checks = 10_000 * 3600 / (900 + 150 + 1.0)
    pushes = 10_000 * 3600 / (3600 + (900 + 150) / 2)  # at the first check after the heartbeat
    assert row["checks_per_hour"] == round(checks) == 34_253
    assert row["report_pushes_per_hour"] == round(pushes) == 8_727
    assert row["git_requests_per_hour"] == round(checks * 1 + pushes * 1)
    push_extra = (15_000 - 9_000) + 64 * (10 - 4)  # the advertisement of one of 1,024 shards: 10 refs, not 10,000
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


def test_an_applying_wake_s_phases_are_read_from_its_journal_line():
    line = pull.LINE.match(
        "robot-pull: applied (release 4): release 4 applied; 7.3 s, 2.10 s CPU, sent 10 B, received 20 B in 3 "
        "requests; report sent [fetch 0.21 s, verify 0.50 s, deploy 4.20 s, status 0.61 s, report 0.30 s]"
    )
    assert line["report"] == "report sent"
    assert pull.phases(line.groupdict()) == {"fetch": 0.21, "verify": 0.5, "deploy": 4.2, "status": 0.61, "report": 0.3}
    idle = pull.LINE.match("robot-pull: idle; 0.1 s, 0.07 s CPU, sent 1 B, received 2 B; r")
    assert pull.phases(idle.groupdict()) == {}


def test_each_phase_s_median_over_the_wakes_that_had_it():
    found = [{"verify": 0.5, "deploy": 4.0}, {"verify": 0.7, "deploy": 5.0, "prepare": 1.0}, {"deploy": 6.0}]
    assert prefetch.median_phases(found) == {"verify": 0.6, "deploy": 5.0, "prepare": 1.0}


def test_the_prefetch_section_has_a_row_per_mode_and_a_dash_for_a_phase_it_did_not_have():
    found = {
        "prefetched": {"runs": 2, "to_healthy_s": 6.47, "applying_wake_s": 5.8, "phases_s": {"deploy": 3.54}},
        "nothing prefetched": {"runs": 0, "to_healthy_s": None, "applying_wake_s": None, "phases_s": {}},
    }
    text = prefetch.markdown(found, {"commit": "abc1234"})
    assert "- commit: abc1234" in text
    assert "| prefetched | 6.47 | 5.80 | - | 2 |" in text and "| nothing prefetched | - | - | - | 0 |" in text
    assert "| prefetched | - | - | - | - | - | - | 3.54 | - | - |" in text


def test_a_prepared_switch_is_done_at_the_wake_s_seconds_less_its_phases_after_it():
    line = pull.LINE.match(
        "robot-pull: applied (release 4): release 4 applied; 6.1 s, 2.10 s CPU, sent 10 B, received 20 B in 3 "
        "requests; report sent [fetch 0.21 s, verify 0.20 s, decide 0.00 s, prepare 0.04 s, switch 1.50 s, "
        "load 1.00 s, deploy 1.80 s, status 0.50 s, report 0.30 s]"
    ).groupdict()
    assert prefetch.until_switched(line) == 2.5  # 6.1 - (1.0 + 1.8 + 0.5 + 0.3)
    whole = pull.LINE.match(
        "robot-pull: applied (release 4): release 4 applied; 7.3 s, 2.10 s CPU, sent 10 B, received 20 B in 3 "
        "requests; report sent [fetch 0.21 s, load 1.00 s, deploy 4.20 s]"
    ).groupdict()
    assert prefetch.until_switched(whole) is None


def staged_run(to_100, longest_apply=12.0, **more):
    return {
        "interval": 60,
        "jitter": 20,
        "staged": True,
        "robots": 10,
        "reached": 10 if to_100 is not None else 7,
        "longest_apply": longest_apply,
        "to_50%": 70.0,
        "to_100%": to_100,
        "bytes_per_update": 1000,
        "load": 0.5,
        "idle": True,
        **more,
    }


def test_a_staged_rollout_is_judged_against_twice_the_check_period_plus_one_apply():
    assert pull.target_of(staged_run(150.0)) == 2 * (60 + 20) + 12.0
    assert pull.within_target(staged_run(172.0)) and not pull.within_target(staged_run(172.5))
    assert not pull.within_target(staged_run(None))  # a robot that never got there
    assert not pull.within_target(staged_run(100.0, longest_apply=None))  # no applying wake in the journals
    figure = pull.rollout_figure([staged_run(150.0), staged_run(180.0)])
    assert figure["staged"] and not figure["within_target"]
    text = pull.markdown({"robots": 10, "staged": figure}, {"date": "d"})
    assert "| 1 | 70.0 | 150.0 | 12.0 | 172.0 | yes |" in text
    assert "| 2 | 70.0 | 180.0 | 12.0 | 172.0 | **no** |" in text
    assert pull.all_idle({"staged": figure}) and not pull.all_idle({"staged": {**figure, "idle": False}})
