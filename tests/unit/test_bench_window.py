"""The benchmarks' reading of Docker's own clocks on a robot
(tests/bench/window.py): what a robot's `ctr events`, `docker inspect` and
`docker events` say, turned into the update window and a broken release's
figures.  The samples are lines a lab robot printed."""

from __future__ import annotations

import json

import pytest

from tests.bench import __main__ as bench
from tests.bench import window

OLD = "d428bab95037142e27de2a83731bd9d65e8eeed3e8c209b6064390202f63642e"
NEW = "6e635894b032266c05aa308755ce59d5da1f180b6607ef0185eb680540ded5d5"
BROKEN = "3166a130532b6a8a1c7e2f0f8cf0f77e54c8bc1b84e3e76d6af4a0bfa1c2b6d0"

CTR = f"""\
2026-11-25 08:42:25.098351344 +0000 UTC moby /tasks/exec-added {{"container_id":"{OLD}","exec_id":"e8b0"}}
2026-11-25 08:42:25.266804747 +0000 UTC moby /tasks/exit {{"container_id":"{OLD}","id":"e8b0","pid":2111,"exited_at":{{"seconds":1795596145,"nanos":265379604}}}}
2026-11-25 08:42:25.653312941 +0000 UTC moby /tasks/start {{"container_id":"{NEW}","pid":2163}}
2026-11-25 08:42:25.550996863 +0000 UTC moby /tasks/exit {{"container_id":"{OLD}","id":"{OLD}","pid":2000,"exited_at":{{"seconds":1795596145,"nanos":450570825}}}}
2026-11-25 08:42:25.603859327 +0000 UTC moby /tasks/delete {{"container_id":"{OLD}","pid":2000}}
"""  # noqa: E501 - ctr events' lines verbatim, as ctr prints them


def inspected(cid, started, finished="0001-01-01T00:00:00Z", running=True, service="payload", version="1.1"):
    return json.dumps(
        {
            "id": cid,
            "service": service,
            "version": version,
            "started": started,
            "finished": finished,
            "running": running,
        }
    )


def test_docker_times_keep_their_nanoseconds():
    assert window.docker_time("2026-11-25T08:42:25.654823062Z") == pytest.approx(1795596145.654823062, abs=1e-6)
    assert window.docker_time("2026-11-25T09:42:25.5+01:00") == pytest.approx(1795596145.5)
    assert window.docker_time("0001-01-01T00:00:00Z") is None
    with pytest.raises(ValueError):
        window.docker_time("yesterday")


def test_containerd_events_give_the_containers_own_exits_not_those_of_health_probes():
    events = window.ctr_events(CTR)
    assert [(e["topic"], e["id"]) for e in events] == [("/tasks/start", NEW), ("/tasks/exit", OLD)]
    assert events[1]["time"] == pytest.approx(1795596145.450570825)  # exited_at: Docker's FinishedAt


def test_the_window_runs_from_the_old_containers_exit_to_the_new_ones_start():
    before = window.containers(inspected(OLD, "2026-11-25T08:40:00.1Z", version="1.0"))
    after = window.containers("Error: noise on stderr\n" + inspected(NEW, "2026-11-25T08:42:25.654823062Z"))
    assert window.update_window(before, after, window.ctr_events(CTR)) == pytest.approx(0.204252237, abs=1e-6)
    # Nothing replaced (the update did not touch the payload): no window.
    assert window.update_window(before, before, window.ctr_events(CTR)) is None
    assert window.update_window(before, after, []) is None  # the old one's exit was not recorded


def test_a_broken_release_is_timed_from_dockers_verdict_and_from_its_first_start():
    before = window.containers(inspected(OLD, "2026-11-25T08:40:00Z", version="1.0"))
    after = window.containers(inspected(NEW, "2026-11-25T08:42:33.5Z", version="1.0"))
    ctr = (
        f'2026-11-25 08:42:26.000000000 +0000 UTC moby /tasks/start {{"container_id":"{BROKEN}","pid":5}}\n'
        "2026-11-25 08:42:33.100000000 +0000 UTC moby /tasks/exit "
        f'{{"container_id":"{BROKEN}","id":"{BROKEN}",'
        f'"exited_at":{{"seconds":1795596153,"nanos":100000000}}}}\n'
    )
    health = window.health_events(
        f"1795596153000000000 {BROKEN} health_status: unhealthy\n1795596150000000000 {BROKEN} health_status: starting\n"
    )
    found = window.broken_release(before, after, window.ctr_events(ctr), health)
    assert found["verdict"] == "unhealthy"  # before its exit (the stop of the rollback)
    assert found["verdict_to_old_running"] == pytest.approx(0.5)
    assert found["first_start_to_old_running"] == pytest.approx(7.5)
    exits_at_once = window.broken_release(before, after, window.ctr_events(ctr), [])
    assert exits_at_once["verdict"] == "exit" and exits_at_once["verdict_to_old_running"] == pytest.approx(0.4)
    assert window.broken_release(before, after, [], health) is None  # no broken container ran


def test_health_check_settings_are_said_in_one_line():
    check = {
        "Test": ["CMD", "/bin/sh", "/healthcheck.sh"],
        "Interval": 2_000_000_000,
        "Timeout": 2_000_000_000,
        "StartPeriod": 2_000_000_000,
        "Retries": 3,
    }
    assert window.describe_healthcheck(check) == ("HEALTHCHECK interval 2 s, timeout 2 s, start period 2 s, retries 3")
    assert window.describe_healthcheck(None) == "no HEALTHCHECK"
    fleet = "all:\n  vars:\n    payload_health_timeout: 60\n"
    assert window.health_settings(lambda command: json.dumps(check) + "\n", "1.0", fleet).endswith(
        "; payload_health_timeout 60 s"
    )


def test_the_results_show_each_robots_window_and_the_broken_releases_settings():
    r = {
        "robots": 10,
        "runs": 3,
        "load_at_start": [0.5],
        "load_at_end": [0.5],
        "figures": {
            "window_all": {
                "median": 0.21,
                "min": 0.18,
                "max": 0.3,
                "samples": [0.18, 0.21, 0.3],
                "loads": [0.5] * 3,
                "idles": [True] * 3,
                "idle": True,
            }
        },
        "window": {"robot1": [0.2, 0.18, 0.25], "robot2": [0.3]},
        "broken_settings": {"runs, never healthy": "verdict: unhealthy; HEALTHCHECK interval 2 s"},
    }
    from tests.bench.fleet import Bench

    Bench.ratios(r)
    text = bench.markdown([r], {})
    assert "robot1 0.20 (0.18–0.25), robot2 0.30" in text
    assert "- runs, never healthy: verdict: unhealthy; HEALTHCHECK interval 2 s" in text
    assert "| max update window (s) | 0.30 |" in text and "update window <= 0.5 s on every robot" in text
