"""Rollout planning without a host: waves, failure budget, resume state
(the rollout command itself: tests/integration/test_waves.py)."""

import os

import pytest

from robotfleet.commands import rollout_plan as waves
from roles.payload import report
from tests.unit.samples import result

ROBOTS = [f"robot{i}" for i in range(1, 11)]


def count(text):
    return waves.parse_count(text, "--batch")


def test_counts_are_numbers_or_percentages_and_anything_else_is_one_line():
    assert count("3") == waves.Count(3, False)
    assert count("25%") == waves.Count(25, True)
    for bad in ("", "-1", "25 %", "1.5", "150%", "x", "03"):
        with pytest.raises(ValueError, match=r"^--batch: expected a number of robots or a percentage like 25%, got "):
            count(bad)


def test_canary_then_batches_in_inventory_order():
    plan = waves.build_waves(ROBOTS, [], count("1"), count("25%"))
    assert plan == [
        ["robot1"],
        ["robot2", "robot3", "robot4"],
        ["robot5", "robot6", "robot7"],
        ["robot8", "robot9", "robot10"],
    ]


def test_flagged_canaries_replace_the_first_n():
    plan = waves.build_waves(ROBOTS[:5], ["robot4", "robot2"], count("1"), count("2"))
    assert plan == [["robot2", "robot4"], ["robot1", "robot3"], ["robot5"]]


def test_no_canary_and_no_batch_is_one_wave_and_tiny_percentages_still_move():
    assert waves.build_waves(ROBOTS[:3], [], count("0"), count("0")) == [ROBOTS[:3]]
    assert waves.build_waves(ROBOTS[:3], [], count("0"), count("1%")) == [[h] for h in ROBOTS[:3]]


def test_every_host_in_exactly_one_wave():
    for canary in ("0", "1", "30%"):
        for batch in ("1", "3", "33%", "100%"):
            plan = waves.build_waves(ROBOTS, [], count(canary), count(batch))
            assert sorted(h for w in plan for h in w) == sorted(ROBOTS) and all(plan)


def test_budget_rounds_shares_down():
    assert waves.allowed_failures(count("10%"), 3) == 0
    assert waves.allowed_failures(count("10%"), 10) == 1
    assert waves.allowed_failures(count("1"), 3) == 1


def state_for(plan, allowed):
    return waves.start_run(waves.new_state("k", "inv.py", plan, {h: "img:2" for w in plan for h in w}, allowed))


def test_a_failure_within_budget_goes_on_and_the_next_one_stops():
    state = state_for([["r1"], ["r2"], ["r3"]], 1)
    state = waves.record_wave(state, 0, [], {"r1": "unhealthy"}, {})
    assert state["status"] == "running"
    state = waves.record_wave(state, 1, [], {"r2": "unhealthy"}, {})
    assert state["status"] == "stopped"
    assert waves.pending(state) == ["r1", "r2", "r3"]


def test_zero_budget_stops_at_the_canary_and_skipped_hosts_do_not_count():
    state = state_for([["r1"], ["r2", "r3"]], 0)
    assert waves.record_wave(state, 0, [], {"r1": "x"}, {})["status"] == "stopped"
    state = waves.record_wave(state, 0, [], {}, {"r1": "unreachable"})
    assert state["status"] == "running"
    state = waves.record_wave(state, 1, ["r2", "r3"], {}, {})
    assert state["status"] == "incomplete" and waves.pending(state) == ["r1"]


def test_a_rerun_resumes_with_a_fresh_budget_and_clears_what_got_done():
    state = state_for([["r1"], ["r2"]], 0)
    state = waves.record_wave(state, 0, [], {"r1": "x"}, {})
    state = waves.start_run(state)
    assert state["status"] == "running" and state["run_failures"] == 0 and state["attempts"] == 2
    state = waves.record_wave(state, 0, ["r1"], {}, {})
    state = waves.record_wave(state, 1, ["r2"], {}, {})
    assert state["status"] == "complete" and state["failed"] == {} and waves.pending(state) == []


def is_done(row: dict, target: str) -> bool:
    return report.missing(row, [target]) is None


def test_done_means_the_target_image_is_current_and_healthy():
    row = {
        "reachable": True,
        "image_refs": ["reg/p:1.1"],
        "release_state": "active",
        "state": "running",
        "health": "healthy",
    }
    assert is_done(row, "reg/p:1.1")
    assert not is_done(row, "reg/p:1.2")
    assert not is_done({**row, "health": "unhealthy"}, "reg/p:1.1")
    assert not is_done({**row, "state": "restarting"}, "reg/p:1.1")
    assert not is_done({**row, "release_state": "failed"}, "reg/p:1.1")
    assert is_done({**row, "release_state": "staged", "state": None, "health": None}, "reg/p:1.1")
    assert not is_done({"reachable": False}, "reg/p:1.1")
    back = {**row, "image_refs": ["reg/p:1.0"], "release": "r1", "rolled_back_from": {"reason": "p is unhealthy"}}
    assert report.missing(back, ["reg/p:1.1"]) == "release failed (p is unhealthy); rolled back to r1"


def test_done_for_a_project_of_several_services_means_every_image():
    """The rollout's target is the whole compose project: a robot running
    driver and slam is done once both run healthy (it used to be failed)."""
    row = {
        "reachable": True,
        "image_refs": ["reg/driver:2", "reg/slam:1"],
        "release_state": "active",
        "state": "driver:running, slam:running",
        "health": "driver:healthy, slam:none",
    }
    assert report.missing(row, ["reg/driver:2", "reg/slam:1"]) is None
    assert report.missing(row, ["reg/driver:3", "reg/slam:1"]) == "runs reg/driver:2, reg/slam:1, not reg/driver:3"
    assert report.missing({**row, "state": "driver:running, slam:restarting"}, ["reg/driver:2", "reg/slam:1"])


def test_the_same_command_finds_the_same_state_file_and_writes_it_atomically(tmp_path):
    key = waves.fleet_key("inventories/robots.py", ["r1", "r2"], {"r1": "a", "r2": "a"})
    assert key == waves.fleet_key("inventories/robots.py", ["r1", "r2"], {"r1": "a", "r2": "a"})
    assert key != waves.fleet_key("inventories/robots.py", ["r1", "r2"], {"r1": "a", "r2": "b"})
    path = waves.state_path(key, str(tmp_path))
    state = state_for([["r1"], ["r2"]], 0)
    waves.save_state(path, state)
    assert waves.load_state(path) == state
    assert os.listdir(tmp_path / ".rollout") == [f"{key}.json"]
    assert waves.latest_state(str(tmp_path)) == state


def test_status_cells_and_summary():
    state = waves.record_wave(state_for([["r1"], ["r2"], ["r3"]], 0), 0, ["r1"], {}, {})
    assert [waves.host_state(state, h) for h in ("r1", "r2", "r9")] == ["wave 1/3 done", "wave 2/3 pending", None]
    assert waves.summary(state) == (
        "rollout k: running after wave 1/3; 1 done, 0 failed, 0 skipped, 2 pending of 3 robot(s); pending: r2, r3"
    )


def test_a_wave_is_judged_from_pyinfra_results_and_release_records():
    from robotfleet.commands.rollout_judge import judge_wave

    good = {
        "reachable": True,
        "image_refs": ["i:2"],
        "release_state": "active",
        "state": "running",
        "health": "healthy",
    }
    back = {
        "reachable": True,
        "image_refs": ["i:1"],
        "release": "r1",
        "release_state": "active",
        "rolled_back_from": {"reason": "unhealthy"},
    }
    results = {
        "operations": [{"name": "Release the payload", "error": ["r2", "r5"]}],
        "failed_hosts": ["r2", "r3", "r5"],
    }
    rows = {
        "r1": good,
        "r2": {**back, "result": result("w1", False, "payload: release x failed")},
        "r3": {"reachable": False, "error": "cannot connect"},
        "r4": back,
        "r5": good,
    }
    targets = dict.fromkeys(rows, {"payload": ["i:2"]})
    done, failed, skipped = judge_wave(list(rows), results, rows, targets, False, deployment="w1")
    assert done == ["r1"]
    assert failed.pop("r2") == "payload: release x failed"  # its own result of this deployment
    assert failed.pop("r4") == "release failed (unhealthy); rolled back to r1"
    # pyinfra failed it although its payload looks fine
    assert failed == {"r5": "the deploy failed at: Release the payload"}
    assert skipped == {"r3": "unreachable: cannot connect"}
    _, failed, skipped = judge_wave(["r3"], None, rows, targets, True, deployment="w1")
    assert failed == {"r3": "unreachable: cannot connect"} and skipped == {}


def test_a_wave_whose_every_host_failed_is_failed_not_unreachable():
    """pyinfra prints no JSON when no host remains ("No hosts remaining!"):
    each robot's own result of this deployment says why."""
    from robotfleet.commands.rollout_judge import judge_wave

    line = "payload: release x failed (p is unhealthy); rolled back to r1 and it is running"
    back = {
        "reachable": True,
        "image_refs": ["i:1"],
        "release": "r1",
        "release_state": "active",
        "result": result("w2", False, line),
    }
    done, failed, skipped = judge_wave(["r1"], None, {"r1": back}, {"r1": {"payload": ["i:2"]}}, False, deployment="w2")
    assert (done, failed, skipped) == ([], {"r1": line}, {})
    # A result of an earlier deployment is not this one's.
    stale = {
        **back,
        "image_refs": ["i:2"],
        "state": "running",
        "health": "healthy",
        "result": result("w1", False, line),
    }
    assert judge_wave(["r1"], None, {"r1": stale}, {"r1": {"payload": ["i:2"]}}, False, deployment="w2")[1] == {
        "r1": "the deploy failed"
    }
    assert judge_wave(
        ["r2"],
        None,
        {"r2": {"reachable": False, "error": "Could not connect (timed out)"}},
        {"r2": {"payload": ["i:2"]}},
        False,
        deployment="w2",
    )[2] == {"r2": "unreachable: Could not connect (timed out)"}


def test_the_state_file_is_written_without_following_anything_planted(tmp_path):
    """The temp file beside the state had a predictable name: a symlink
    planted there made the rollout write through it (issue 17, item 9)."""
    path = str(tmp_path / ".rollout" / "k.json")
    os.makedirs(tmp_path / ".rollout")
    victim = tmp_path / "victim"
    victim.write_text("precious\n")
    os.symlink(victim, f"{path}.{os.getpid()}.tmp")
    waves.save_state(path, {"key": "k"})
    assert victim.read_text() == "precious\n"
    assert waves.load_state(path) == {"key": "k"}


def test_a_second_rollout_of_the_same_fleet_refuses_while_the_first_runs(tmp_path):
    path = waves.lock_path("inventories/robots.py", ["/fleet.yaml"], str(tmp_path))
    with waves.held(path):
        with pytest.raises(waves.RolloutBusy) as busy:
            with waves.held(path):
                pass
        assert str(busy.value).startswith(f"another rollout of this fleet is running (pid {os.getpid()} since 20")
    with waves.held(path):  # free again once the first is done
        pass
    assert path != waves.lock_path("inventories/robots.py", ["/other.yaml"], str(tmp_path))
