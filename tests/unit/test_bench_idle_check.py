"""tests/bench/idle_check.py's arithmetic: a month of checks at 15 minutes, with and without the heartbeat."""

from __future__ import annotations

from tests.bench import idle_check


def check(cpu: float, sent: int, received: int) -> dict:
    return {"cpu": cpu, "sent": sent, "received": received, "connections": 1, "load": 0.5, "line": ""}


def test_a_month_is_2880_checks_and_the_heartbeat_720_of_them():
    found = {
        "idle": [check(0.04, 500, 1500)] * 3,
        "old": [check(0.3, 3000, 6000)] * 3,
        "heartbeat": check(0.2, 4000, 4000),
    }
    lines = idle_check.show("static", found)
    assert "0.040 s CPU" in lines[0] and "target 0.05" not in lines[0] and "target 2048 B: met" in lines[0]
    assert "5.76 MB idle only" in lines[1]  # 2,000 B x 2,880
    assert "10.08 MB with the hour's heartbeat" in lines[1]  # 2,000 x 2,160 + 8,000 x 720
    found["idle"] = [check(0.2, 3000, 2000)] * 3
    assert "target" not in idle_check.show("ssh", found)[0]  # the CPU targets: withdrawn (issue 53)
