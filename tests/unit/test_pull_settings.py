"""Pull mode's settings, declared once by the pull role (issue 37 item 2):
the agent's agent.json takes the same defaults and bounds, status reads the
declared defaults, and the engine reads them only through the role's ``pull``
part (robotfleet/role.py PullPart).  tests/unit/test_architecture.py checks
that no engine module reads a role's setting by name."""

from __future__ import annotations

import dataclasses
import datetime
import json

import pytest

from robotfleet import deploy_roles
from robotfleet.commands import pullstatus
from robotfleet.fleet import connection
from robotfleet.pull.protocol import agent_files, reports
from robotfleet.role import NO_PULL, pull_part
from roles.pull import plan
from roles.pull.settings import SETTINGS

DECLARED = {setting.name: setting for setting in SETTINGS}
# The agent's whole numbers and the pull role's settings that give them.
NUMBERS = {
    "interval": "pull_interval",
    "jitter": "pull_jitter",
    "min_free_mb": "pull_min_free_mb",
    "fetch_timeout": "pull_fetch_timeout",
    "stale_after": "pull_stale_after",
    "heartbeat": "pull_heartbeat",
    "report_shards": "pull_report_shards",
}


def test_every_pull_setting_is_the_pull_role_s():
    assert {"pull_enabled", "pull_platform"} <= set(DECLARED)
    assert not [s.name for s in connection.SETTINGS if s.name == "pull" or s.name.startswith("pull_")]
    assert pull_part(deploy_roles.roles()) is plan.PART


@pytest.mark.parametrize("field", sorted(NUMBERS))
def test_agent_json_and_the_fleet_file_take_one_default_and_one_range(field):
    setting = DECLARED[NUMBERS[field]]
    low, high = agent_files.LIMITS[field]
    assert setting.default == agent_files.default(field)
    assert [bool(setting.check(v)) for v in (low - 1, low, high, high + 1)] == [True, False, False, True]
    config = dataclasses.asdict(agent_files.Config(robot="robot1", remote="ssh://g@h/fleet"))
    for value, refused in ((low - 1, True), (low, False), (high, False), (high + 1, True)):
        text = json.dumps({"format": agent_files.FORMAT, **config, field: value})
        if refused:
            with pytest.raises(agent_files.ConfigError, match=f"{field}: expected a whole number from {low} to {high}"):
                agent_files.read_config(text)
        else:
            assert getattr(agent_files.read_config(text), field) == value


@pytest.mark.parametrize(
    "field, value, range_",
    [("interval", 9, "10 to 604800"), ("heartbeat", 1, "10 to 604800"), ("fetch_timeout", 4, "5 to 86400")],
)
def test_agent_json_refuses_what_the_fleet_file_refuses(field, value, range_):
    """The three the agent once took below the fleet file's minimum (1 s)."""
    assert DECLARED[NUMBERS[field]].check(value)
    text = json.dumps({"format": agent_files.FORMAT, "robot": "robot1", "remote": "ssh://g@h/fleet", field: value})
    with pytest.raises(agent_files.ConfigError, match=f"{field}: expected a whole number from {range_}, got {value}"):
        agent_files.read_config(text)


def test_the_agent_s_config_is_the_host_s_settings_with_their_declared_defaults():
    config = plan.config({"pull_enabled": True, "pull_remote": "ssh://g@h/fleet", "pull_interval": 60}, "robot1")
    assert (config.remote, config.interval, config.jitter, config.heartbeat, config.stale_after) == (
        "ssh://g@h/fleet",
        60,
        300,
        3600,
        2,
    )
    assert config.media_dir is None and config.report_remote is None and config.report_shards == 0
    assert plan.pulls({"pull_enabled": True}) and not plan.pulls({}) and not plan.pulls({"pull_enabled": False})
    assert "OnUnitInactiveSec=60\n" in plan.timer_unit({"pull_interval": 60})
    assert "OnBootSec=60\n" in plan.timer_unit({})


def test_without_a_pull_role_no_host_pulls():
    assert pull_part(()) is NO_PULL and not NO_PULL.pulls({"pull_enabled": True})
    with pytest.raises(LookupError, match="no role of deploy.py declares pull mode"):
        NO_PULL.config({"pull_enabled": True}, "robot1")


def test_status_judges_a_report_by_the_declared_defaults_not_by_what_the_report_says():
    """A report's own numbers (here a heartbeat of 0) never set the stale
    limit: the host's settings do, with the pull role's defaults (900 s
    interval, 300 s jitter, 3600 s heartbeat, 2 heartbeats)."""
    made = datetime.datetime(2026, 11, 25, 10, tzinfo=datetime.timezone.utc)
    config = agent_files.Config(robot="robot1", remote="ssh://g@h/fleet", interval=60, jitter=0, heartbeat=10)
    report = reports.build("robot1", made, "up-to-date", config=config)
    limit = 2 * (3600 + 900 + 300)
    fresh = pullstatus.row("robot1", report, {}, made + datetime.timedelta(seconds=limit), "url")
    late = pullstatus.row("robot1", report, {}, made + datetime.timedelta(seconds=limit + 1), "url")
    assert fresh["stale"] is False and fresh["reachable"] == "pull"
    assert late["stale"] is True and f"({limit} s) ago" in late["error"]
