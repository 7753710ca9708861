"""status's table as it fits a terminal (issue 54, item 3): the default
columns within 100 characters for a typical fleet, every column with -o
wide, a summary line of the hosts' states, pull robots in their own words."""

from __future__ import annotations

import json
import re

from robotfleet import deploy_roles, status_parts
from robotfleet.commands import status
from robotfleet.commands.pull import status as pullstatus

RELEASE = "20261121T204438Z-dadf84de"


def split(line: str) -> list[str]:
    return re.split(r"\s{2,}", line.strip())


def roles():
    return deploy_roles.roles()


def answered(name: str, health: str = "healthy", drift=None) -> dict:
    report = {
        "current": {
            "id": RELEASE,
            "state": "active",
            "activated": "2026-11-21T20:44:42Z",
            "images": {
                "registry.example.com/acme/ros-payload:1.4.2": {"id": "sha256:1", "pinned": "x@sha256:" + "d" * 64}
            },
        },
        "previous": {"id": "20261120T101010Z-0badcafe"},
        "containers": [{"status": "running", "health": health, "restarts": 0}],
        "update_lock": None,
    }
    parts = {status_parts.HOST_SECTION: "amd64\n", "docker": "28.5.2", "payload": json.dumps(report)}
    row = status_parts.row(name, roles(), parts)
    row.update(drift=drift, rollout="wave 12/20 pending")
    return row


def fleet() -> list[dict]:
    return [
        answered("warehouse-01"),
        answered("warehouse-02", health="unhealthy", drift="release is active, containers running/unhealthy"),
        status_parts.row("warehouse-03", roles(), None, "timed out after 10 s connecting to 10.0.0.3:22 (...)"),
        status_parts.row("warehouse-04", roles(), None, "host key CHANGED: known_hosts has SHA256:a ..."),
        {"host": "warehouse-05", "reachable": False, "via": "report", "pull": "no report", "error": "no report"},
    ]


def test_the_default_columns_fit_100_characters_and_wide_has_every_one():
    """Host names of 12 characters, a pull robot without a report, an unhealthy release, the 12th of 20 waves."""
    rows = fleet()
    narrow = status.table(rows, status_parts.columns(roles(), wide=False)).splitlines()
    assert max(len(line) for line in narrow) <= 100, "\n".join(narrow)
    assert split(narrow[0]) == ["HOST", "REACHABLE", "RELEASE", "STATE", "HEALTH", "ROLLOUT"]
    wide = status.table(rows, status_parts.columns(roles())).splitlines()
    assert max(len(line) for line in wide) > 100
    for title in ("ARCH", "DOCKER", "IMAGE", "PREVIOUS", "LAST DEPLOY", "LOCK", "GPU DRIVER"):
        assert title in wide[0], title


def test_the_summary_counts_each_state():
    rows = fleet()
    assert [status_parts.state_of(r) for r in rows] == ["healthy", "drifted", "unreachable", "failed", "unreachable"]
    assert status.summary(rows) == "1 healthy, 1 drifted, 1 failed, 2 unreachable"
    assert status.summary([answered("a"), answered("b"), answered("c")]) == "3 healthy"
    assert status.summary([]) == "no host"


def test_pull_robots_in_their_own_words():
    rows = fleet()
    line = status.table(rows, status_parts.columns(roles(), wide=False)).splitlines()[-1]
    assert split(line)[:2] == ["warehouse-05", "pull: no report yet"]
    assert "no: no report" not in line


def test_a_pull_robot_s_last_report_is_its_rollout_in_the_default_table():
    """The pull guide's step 8 reads what each robot did (applied 1, waiting 1, ...) from the
    default table; -o wide has it in PULL, beside REPORTED."""
    reported = {"host": "warehouse-06", "reachable": "pull", "via": "report", "release": RELEASE, "health": "healthy"}
    rows = [*fleet(), dict(reported, pull="prefetched 12")]
    narrow = status.table(rows, status_parts.columns(roles(), wide=False)).splitlines()
    assert max(len(line) for line in narrow) <= 100, "\n".join(narrow)
    assert split(narrow[-1])[-1] == "prefetched 12" and split(narrow[1])[-1] == "wave 12/20 pending"
    wide = status.table(rows, status_parts.columns(roles())[:-1] + pullstatus.COLUMNS + [("rollout", "ROLLOUT")])
    assert split(wide.splitlines()[-1])[-3:] == ["prefetched 12", "-", "-"]
