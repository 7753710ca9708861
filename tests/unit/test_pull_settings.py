"""Pull mode's settings, the engine's own and declared once
(robotfleet/fleet/pull_mode.py; issue 37 item 2, issue 53 item 1): the
agent's agent.json takes the same defaults and bounds, status reads the
declared defaults, and the pull role declares none."""

from __future__ import annotations

import dataclasses
import datetime
import json

import pytest

from robotfleet import deploy_roles
from robotfleet.commands.pull import status as pullstatus
from robotfleet.fleet import connection, pull_mode
from robotfleet.pull.protocol import agent_files, reports

DECLARED = {setting.name: setting for setting in (*pull_mode.SETTINGS, *connection.SETTINGS)}
# The agent's whole numbers and the settings that give them.
NUMBERS = agent_files.NUMBERS


def test_every_pull_setting_is_the_engine_s_and_no_role_s():
    assert {"pull_enabled", "pull_platform"} <= {s.name for s in pull_mode.SETTINGS}
    assert all(s.name.startswith("pull_") for s in pull_mode.SETTINGS)
    assert not [s.name for s in connection.SETTINGS if s.name == "pull" or s.name.startswith("pull_")]
    assert not [(r.name, s.name) for r in deploy_roles.roles() for s in r.settings if s.name.startswith("pull")]
    assert all(deploy_roles.registry().settings[s.name] is s for s in pull_mode.SETTINGS)


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
    config = agent_files.for_host(
        {"pull_enabled": True, "pull_remote": "ssh://g@h/fleet", "pull_interval": 60}, "robot1"
    )
    assert (config.remote, config.interval, config.jitter, config.heartbeat, config.stale_after) == (
        "ssh://g@h/fleet",
        60,
        300,
        3600,
        2,
    )
    assert config.media_dir is None and config.report_remote is None and config.report_shards == 0
    assert pull_mode.pulls({"pull_enabled": True}) and not pull_mode.pulls({})
    assert not pull_mode.pulls({"pull_enabled": False})
    assert "OnUnitInactiveSec=60\n" in agent_files.timer_unit({"pull_interval": 60})
    assert "OnBootSec=60\n" in agent_files.timer_unit({})


def test_the_fleet_check_refuses_a_window_as_the_agent_does():
    from robotfleet.pull.protocol import waves

    for text in ("Mon-Fri 01:00-01:00", "daily 1:05-01:05 UTC"):
        with pytest.raises(ValueError) as refused:
            waves.parse_window(text)
        assert pull_mode.window(text) == [("", str(refused.value))]
    assert pull_mode.window("Mon-Fri 01:00-05:00") == [] and pull_mode.window("daily 22:00-02:00 UTC") == []


def test_status_judges_a_report_by_the_declared_defaults_not_by_what_the_report_says():
    """A report's own numbers (here a heartbeat of 0) never set the stale
    limit: the host's settings do, with their declared defaults (900 s
    interval, 300 s jitter, 3600 s heartbeat, 2 heartbeats)."""
    made = datetime.datetime(2026, 11, 25, 10, tzinfo=datetime.timezone.utc)
    config = agent_files.Config(robot="robot1", remote="ssh://g@h/fleet", interval=60, jitter=0, heartbeat=10)
    report = reports.build("robot1", made, "up-to-date", config=config)
    limit = 2 * (3600 + 900 + 300)
    fresh = pullstatus.row("robot1", report, {}, made + datetime.timedelta(seconds=limit), "url")
    late = pullstatus.row("robot1", report, {}, made + datetime.timedelta(seconds=limit + 1), "url")
    assert fresh["stale"] is False and fresh["reachable"] == "pull"
    assert late["stale"] is True and f"({limit} s) ago" in late["error"]
