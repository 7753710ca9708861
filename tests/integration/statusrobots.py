"""Robots as ``robotfleet status`` finds them over SSH, for the SSH servers
of tests/integration/sshserver.py to play: a payload's status report and
the answer to the status command (test_metrics.py, test_status_page.py)."""

from __future__ import annotations

import json

RELEASE = "20261121T204438Z-dadf84de"
IMAGE = "reg.example.com/p:1"


def report(release=RELEASE, health="healthy", image=IMAGE):
    return {
        "current": {
            "id": release,
            "state": "active",
            "activated": "2026-11-21T20:44:42Z",
            "images": {image: {"pinned": "reg.example.com/p@sha256:" + "a" * 64}},
        },
        "previous": {"id": "20261120T000000Z-0badcafe"},
        "containers": [{"status": "running", "health": health, "restarts": 2}],
    }


def robot(answer_report: dict):
    def answer(command: str):
        return (
            f"@@@robot-fleet-status engine:host\namd64\n@@@robot-fleet-status payload\n{json.dumps(answer_report)}\n"
        ).encode(), 0

    return answer
