"""What rollout and status print (issue 28, item 10; issue 27, item 4): one
line per robot with its outcome and reason, a summary whose counts add up to
the robots of the rollout (also when it is resumed), and nothing a robot
sends obeyed by the operator's terminal.  A real SSH server on 127.0.0.1
plays a robot whose answers carry terminal escape sequences; closed ports
play dead robots."""

from __future__ import annotations

import json
import re

import pytest

from robotfleet.commands import rollout_plan, rolloutreport
from tests.integration import sshserver
from tests.integration.operator_side import fleet, run

# An OSC that retitles the terminal, a bell, a screen clear, a cursor move.
EVIL = "\x1b]0;owned\x07\x1b[2J\x1b[1;1H"
SHOWN = "\\x1b]0;owned\\x07\\x1b[2J\\x1b[1;1H"
REPORT = {
    "current": {
        "id": f"r1{EVIL}",
        "state": "active",
        "images": {f"reg.example.com/p:9{EVIL}": {"pinned": "reg.example.com/p@sha256:" + "a" * 64}},
    },
    "containers": [{"status": f"running{EVIL}", "health": "healthy"}],
}


def evil_robot(command: str):
    """A robot whose status report and every other answer carry escapes."""
    if "@@@robot-fleet-status" in command:
        return (
            f"@@@robot-fleet-status engine:host\namd64{EVIL}\n@@@robot-fleet-status payload\n{json.dumps(REPORT)}\n"
        ).encode(), 0
    return f"payload: release failed{EVIL}\n".encode(), 1


@pytest.fixture
def robots(tmp_path, client_key):
    server = sshserver.ssh_server(client_key, evil_robot)
    closed = sshserver.closed_port()
    path = fleet(
        tmp_path,
        {
            "robot1": {"address": "127.0.0.1", "ssh_port": server.port},
            "robot2": {"address": "127.0.0.1", "ssh_port": closed},
            "robot3": {"address": "127.0.0.1", "ssh_port": closed},
        },
        ssh_strict_host_key_checking="accept-new",
        ssh_connect_retries=0,
    )
    yield path, server
    server.close()


def obeyable(text: str) -> list[str]:
    """Control characters a terminal would act on (newlines and tabs aside)."""
    return sorted({hex(ord(c)) for c in text if (ord(c) < 0x20 and c not in "\n\t") or 0x7F <= ord(c) < 0xA0})


def test_robot_text_is_shown_not_obeyed_in_status(tmp_path, robots):
    path, _ = robots
    result = run(path, tmp_path, "-m", "robotfleet", "status", "inventories/robots.py", "--limit", "robot1")
    assert result.returncode == 0, result.stderr
    assert obeyable(result.stdout + result.stderr) == []
    assert f"r1{SHOWN}" in result.stdout and f"running{SHOWN}" in result.stdout
    as_json = run(path, tmp_path, "-m", "robotfleet", "status", "inventories/robots.py", "--limit", "robot1", "--json")
    assert obeyable(as_json.stdout) == [] and json.loads(as_json.stdout)[0]["release"] == f"r1{EVIL}"


def rollout_lines(output: str) -> dict[str, list[str]]:
    found: dict[str, list[str]] = {}
    for line in output.splitlines():
        match = re.match(r"rollout: \[(robot\d)\] ", line)
        if match:
            found.setdefault(match.group(1), []).append(line)
    return found


def test_one_line_per_robot_counts_that_add_up_and_nothing_obeyed_in_rollout(tmp_path, robots):
    path, server = robots
    argv = [
        "-m",
        "robotfleet",
        "rollout",
        "inventories/robots.py",
        "-y",
        "--canary",
        "0",
        "--batch",
        "100%",
        "--max-failed",
        "3",
    ]
    first = run(path, tmp_path, *argv)
    assert first.returncode == 1, first.stderr[-3000:]
    assert obeyable(first.stdout + first.stderr) == [], first.stderr[-3000:]
    lines = rollout_lines(first.stderr)
    assert {host: len(found) for host, found in lines.items()} == {"robot1": 1, "robot2": 1, "robot3": 1}
    assert lines["robot1"][0].startswith("rollout: [robot1] failed: ")
    assert lines["robot2"][0].startswith("rollout: [robot2] skipped: unreachable: connection refused by 127.0.0.1:")
    assert re.search(rf"robot1 +1/1 +failed +r1{re.escape(SHOWN)} ", first.stdout), first.stdout
    assert "0 done, 1 failed, 2 skipped, 0 pending of 3 robot(s)" in first.stdout

    server.close()  # the same command again, resumed: robot1 is now as dead as the others
    second = run(path, tmp_path, *argv)
    assert second.returncode == 3, second.stderr[-3000:]
    assert {host: len(found) for host, found in rollout_lines(second.stderr).items()} == {
        "robot1": 1,
        "robot2": 1,
        "robot3": 1,
    }
    assert "0 done, 0 failed, 3 skipped, 0 pending of 3 robot(s)" in second.stdout, second.stdout


def state_for(plan):
    return rollout_plan.start_run(rollout_plan.new_state("k", "inv.py", plan, {h: "img:2" for w in plan for h in w}, 1))


def test_each_robot_has_one_outcome_whatever_the_runs():
    state = state_for([["r1"], ["r2", "r3"]])
    state = rollout_plan.record_wave(state, 0, [], {"r1": "unhealthy"}, {})
    state = rollout_plan.start_run(state)
    state = rollout_plan.record_wave(state, 0, [], {}, {"r1": "unreachable: timed out"})
    state = rollout_plan.record_wave(state, 1, ["r2"], {"r3": "unhealthy"}, {})
    assert [rollout_plan.outcome(state, h) for h in ("r1", "r2", "r3")] == ["skipped", "done", "failed"]
    assert [rolloutreport.robot_line(state, h) for h in ("r1", "r2", "r3")] == [
        "rollout: [r1] skipped: unreachable: timed out",
        "rollout: [r2] done",
        "rollout: [r3] failed: unhealthy",
    ]
    assert "; 1 done, 1 failed, 1 skipped, 0 pending of 3 robot(s);" in rollout_plan.summary(state)
