"""Fleet state where operators already watch their machines (issue 28, item
13): ``robotfleet status --metrics FILE`` / ``--format openmetrics`` write
OpenMetrics text that the Prometheus client library's parsers (OpenMetrics
and the classic text format, as node_exporter's textfile collector and a
Pushgateway read it) take, with each robot's reachability, release, health,
last change and drift.  Real SSH servers on 127.0.0.1 play the robots."""

from __future__ import annotations

import os
import stat
import time

import pytest
from prometheus_client import parser as text_format
from prometheus_client.openmetrics import parser as openmetrics

from robotfleet import deploy_roles
from robotfleet.commands import metrics
from tests.integration import sshserver
from tests.integration.operator_side import fleet, run
from tests.integration.statusrobots import IMAGE, RELEASE, report, robot


@pytest.fixture
def robots(tmp_path, client_key):
    servers = {
        "robot1": sshserver.ssh_server(client_key, robot(report())),
        "robot2": sshserver.ssh_server(client_key, robot(report(health="unhealthy"))),
        "robot3": sshserver.ssh_server(client_key, robot(report(image="reg.example.com/p:0"))),
    }
    hosts = {name: {"address": "127.0.0.1", "ssh_port": server.port} for name, server in servers.items()}
    hosts["robot4"] = {"address": "127.0.0.1", "ssh_port": sshserver.closed_port()}
    path = fleet(tmp_path, hosts, payload_image=IMAGE, ssh_strict_host_key_checking="accept-new", ssh_connect_retries=0)
    yield path, servers
    for server in servers.values():
        server.close()


def by_host(families, name: str) -> dict[str, float]:
    return {s.labels["host"]: s.value for f in families if f.name == name for s in f.samples}


def test_status_writes_openmetrics_that_prometheus_parsers_read(tmp_path, robots):
    path, _ = robots
    target = tmp_path / "textfile" / "robotfleet.prom"
    target.parent.mkdir()
    started = time.time()
    result = run(
        path,
        tmp_path,
        "-m",
        "robotfleet",
        "status",
        "inventories/robots.py",
        "--format",
        "openmetrics",
        "--metrics",
        str(target),
    )
    assert result.returncode == 3, result.stderr  # robot4 is unreachable
    assert target.read_text() == result.stdout and result.stdout.endswith("# EOF\n")
    families = list(openmetrics.text_string_to_metric_families(result.stdout))
    classic = list(text_format.text_string_to_metric_families(result.stdout))
    assert {f.name for f in classic} == {f.name for f in families}
    assert all(f.type == "gauge" for f in families)
    assert by_host(families, "robotfleet_up") == {"robot1": 1, "robot2": 1, "robot3": 1, "robot4": 0}
    assert by_host(families, "robotfleet_drift") == {"robot1": 0, "robot2": 1, "robot3": 1}
    assert by_host(families, "robotfleet_payload_healthy") == {"robot1": 1, "robot2": 0, "robot3": 1}
    assert by_host(families, "robotfleet_payload_last_change_timestamp_seconds")["robot1"] == 1795293882
    [info] = [
        s
        for f in families
        if f.name == "robotfleet_payload_release_info"
        for s in f.samples
        if s.labels["host"] == "robot1"
    ]
    assert info.labels == {
        "host": "robot1",
        "kind": "robots",
        "via": "ssh",
        "release": RELEASE,
        "state": "active",
        "previous": "20261120T000000Z-0badcafe",
    }
    [stamp] = [s.value for f in families if f.name == "robotfleet_status_timestamp_seconds" for s in f.samples]
    assert started <= stamp <= time.time()


def test_the_file_is_replaced_atomically_and_readable_by_the_collector(tmp_path, robots):
    path, _ = robots
    target = tmp_path / "robotfleet.prom"
    target.write_text("old\n")
    before = os.stat(target).st_ino
    result = run(
        path,
        tmp_path,
        "-m",
        "robotfleet",
        "status",
        "inventories/robots.py",
        "--limit",
        "robot1",
        "--metrics",
        str(target),
    )
    assert result.returncode == 0, result.stderr
    assert os.stat(target).st_ino != before  # a new file renamed over the old one, never rewritten in place
    assert stat.S_IMODE(os.stat(target).st_mode) == 0o644
    assert sorted(os.listdir(tmp_path)) == sorted(["robotfleet.prom", "fleet.yaml", "known_hosts", "id_fleet"])
    assert "HOST" in result.stdout  # the table still goes to the terminal


def test_an_unwritable_metrics_file_is_refused_before_any_host_is_contacted(tmp_path, robots):
    path, servers = robots
    result = run(
        path,
        tmp_path,
        "-m",
        "robotfleet",
        "status",
        "inventories/robots.py",
        "--metrics",
        str(tmp_path / "missing" / "robotfleet.prom"),
    )
    assert result.returncode == 2
    assert result.stderr.strip() == (
        f"status: --metrics {tmp_path}/missing/robotfleet.prom: cannot write in "
        f"{tmp_path}/missing (no such directory, or not writable); no host was contacted"
    )
    assert all(server.connections == 0 for server in servers.values())


def test_robot_supplied_labels_are_escaped_and_round_trip():
    row = {
        "host": "robot1",
        "kind": "robots",
        "reachable": True,
        "drift": None,
        "release": 'r"1\\\x1b[2J\nx',
        "release_state": "active",
        "state": "running",
        "health": "healthy",
    }
    text = metrics.render([row], deploy_roles.roles(), 0)
    [info] = [
        s
        for f in openmetrics.text_string_to_metric_families(text)
        if f.name.endswith("release_info")
        for s in f.samples
    ]
    assert info.labels["release"] == 'r"1\\\\x1b[2J\\x0ax'
    assert "\x1b" not in text


def test_robots_that_report_by_themselves_join_through_the_reporters(monkeypatch):
    """The extension point for pull-mode robots: a reporter's rows are
    rendered like status's own, labelled with where they came from."""

    def pulled(inventory: str, reached: list[str]) -> list[dict]:
        return [
            {
                "host": "robot9",
                "kind": "robots",
                "via": "pull",
                "reachable": True,
                "drift": None,
                "release": "r9",
                "release_state": "active",
                "state": "running",
                "health": "healthy",
            }
        ]

    monkeypatch.setattr(metrics, "REPORTERS", [pulled])
    rows = [{"host": "robot1", "kind": "robots", "reachable": False}] + metrics.reported("inv.py", ["robot1"])
    families = list(openmetrics.text_string_to_metric_families(metrics.render(rows, deploy_roles.roles(), 0)))
    up = {
        (s.labels["host"], s.labels["via"]): s.value for f in families if f.name == "robotfleet_up" for s in f.samples
    }
    assert up == {("robot1", "ssh"): 0, ("robot9", "pull"): 1}


def test_pull_robots_are_in_the_metrics_from_their_reports_stale_marked(tmp_path):
    """status --format openmetrics over pull robots: read from their reports
    on the fleet remote (no SSH), labelled via="report"; a stale report is
    up 0 and pull_report_stale 1 with no role gauges, a refusal is
    pull_failed 1, a robot without a report is up 0 and stale."""
    import datetime
    import subprocess
    import sys

    from robotfleet.pull.protocol import reports
    from robotfleet.pull.robot import transport

    bare = tmp_path / "fleet.git"
    subprocess.run(["git", "init", "-q", "--bare", str(bare)], check=True)
    now = datetime.datetime.now(datetime.timezone.utc).replace(microsecond=0)
    cells = {"release": RELEASE, "release_state": "active", "state": "running", "health": "healthy"}
    config = type("Config", (), {"interval": 60, "jitter": 5, "stale_after": 3, "heartbeat": 0})
    made = {
        "robot1": reports.build(
            "robot1",
            now,
            "up-to-date",
            seen={"version": 7, "release": "r7", "commit": "a" * 40},
            applied={"version": 7, "release": "r7", "commit": "a" * 40, "time": "2026-11-25T09:59:00Z"},
            status=cells,
            config=config,
        ),
        "robot2": reports.build(
            "robot2",
            now - datetime.timedelta(hours=2),
            "applied",
            status=cells,
            config=config,
            applied={"version": 6, "release": "r6", "commit": "b" * 40, "time": "2026-11-24T09:59:00Z"},
        ),
        "robot3": reports.build(
            "robot3",
            now,
            "refused",
            refusal="tampered",
            reason="targets.json: changed",
            seen={"version": 8, "release": "r8", "commit": "c" * 40},
            status=cells,
            config=config,
        ),
    }
    for name, made_report in made.items():
        transport.Remote(f"file://{bare}", tmp_path / name, str(tmp_path / "etc"), timeout=30).push_report(
            name, reports.to_bytes(made_report)
        )
    inventory = tmp_path / "inv.py"
    # Addresses nothing listens on: a connection attempt would be an error row, not a report's.
    # Status judges a report's age by the fleet's settings, not by what the report says it was told.
    pull = '"pull_enabled": True, "pull_interval": 60, "pull_jitter": 5, "pull_stale_after": 3, "pull_heartbeat": 10'
    inventory.write_text(
        "robots = ["
        + ", ".join(f'("robot{i}", {{{pull}, "ssh_hostname": "192.0.2.{i}"}})' for i in range(1, 5))
        + "]\n"
    )
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "robotfleet",
            "status",
            str(inventory),
            "--remote",
            f"file://{bare}",
            "--format",
            "openmetrics",
        ],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        timeout=120,
    )
    assert result.returncode == 1, result.stderr  # robot3 refused its release
    families = list(openmetrics.text_string_to_metric_families(result.stdout))
    assert {f.name for f in text_format.text_string_to_metric_families(result.stdout)} == {f.name for f in families}
    up = {
        (s.labels["host"], s.labels["via"], s.labels["kind"]): s.value
        for f in families
        if f.name == "robotfleet_up"
        for s in f.samples
    }
    assert up == {
        ("robot1", "report", "robots"): 1,
        ("robot2", "report", "robots"): 0,
        ("robot3", "report", "robots"): 1,
        ("robot4", "report", "robots"): 0,
    }
    assert by_host(families, "robotfleet_pull_report_stale") == {"robot1": 0, "robot2": 1, "robot3": 0, "robot4": 1}
    assert by_host(families, "robotfleet_pull_report_timestamp_seconds") == {
        "robot1": now.timestamp(),
        "robot2": (now - datetime.timedelta(hours=2)).timestamp(),
        "robot3": now.timestamp(),
    }
    assert by_host(families, "robotfleet_pull_applied_version") == {"robot1": 7, "robot2": 6}
    assert by_host(families, "robotfleet_pull_seen_version") == {"robot1": 7, "robot3": 8}
    assert by_host(families, "robotfleet_pull_failed") == {"robot1": 0, "robot2": 0, "robot3": 1}
    results = {
        s.labels["host"]: (s.labels["result"], s.labels["refusal"])
        for f in families
        if f.name == "robotfleet_pull_result_info"
        for s in f.samples
    }
    assert results == {"robot1": ("up-to-date", ""), "robot2": ("applied", ""), "robot3": ("refused", "tampered")}
    # The roles' gauges come from fresh reports only: a stale one does not vouch for the robot now.
    assert by_host(families, "robotfleet_payload_healthy") == {"robot1": 1, "robot3": 1}
    assert set(by_host(families, "robotfleet_drift")) == {"robot1", "robot3"}
