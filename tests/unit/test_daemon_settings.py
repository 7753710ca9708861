"""daemon.json is written in one place (roles/docker/__init__.py daemon_json,
which the converged-host fixture uses too): a new daemon.json setting is one
DaemonSetting line in roles/docker/settings.py and its line in SAMPLES here."""

from __future__ import annotations

import json

import pytest

from robotfleet import checkers as c
from roles.docker import settings
from roles.docker.settings import DaemonSetting
from tests.unit.harness import ROBOT, converged, find, fresh_host, plan, written_files

DAEMON_JSON = "/etc/docker/daemon.json"
# Each DaemonSetting: a value to set, and what daemon.json then holds under
# its key (the default docker_daemon_options have neither key).
SAMPLES = {
    "docker_registry_mirrors": (["https://mirror.lan"], ["https://mirror.lan"]),
    "docker_insecure_registries": (["registry.lan:5000"], ["registry.lan:5000"]),
}


def daemon_settings() -> dict[str, DaemonSetting]:
    return {s.name: s for s in settings.SETTINGS if isinstance(s, DaemonSetting)}


def planned_daemon_json(data: dict) -> dict:
    return json.loads(written_files(plan({"r1": ("robots", data, fresh_host("debian-13"))})["r1"])[DAEMON_JSON])


def test_every_daemon_setting_has_a_sample():
    assert set(SAMPLES) == set(daemon_settings())


@pytest.mark.parametrize("name", sorted(SAMPLES))
def test_a_daemon_setting_is_written_under_its_key_and_a_converged_host_plans_nothing(name):
    value, written = SAMPLES[name]
    setting = daemon_settings()[name]
    assert setting.check(value) == []
    data = {**ROBOT, name: value}
    assert planned_daemon_json(data)[setting.key] == written
    assert setting.key not in planned_daemon_json(ROBOT)
    snap = converged("robots", data, "debian-13")
    assert not find(plan({"r1": ("robots", data, snap)})["r1"], "daemon.json")


def test_a_new_daemon_setting_is_one_declaration(monkeypatch):
    """ARCHITECTURE.md's example, docker_ipv6: declared, it reaches the planned
    daemon.json and the converged host with no other change."""
    ipv6 = DaemonSetting(
        "docker_ipv6", None, c.optional(c.boolean), "Enable IPv6 for containers (daemon.json ipv6).", key="ipv6"
    )
    monkeypatch.setattr(settings, "SETTINGS", (*settings.SETTINGS, ipv6))
    data = {**ROBOT, "docker_ipv6": True}
    assert planned_daemon_json(data)["ipv6"] is True
    assert planned_daemon_json({**ROBOT, "docker_ipv6": False})["ipv6"] is False
    assert "ipv6" not in planned_daemon_json(ROBOT)  # unset (null): the key is left to docker_daemon_options
    snap = converged("robots", data, "debian-13")
    assert not find(plan({"r1": ("robots", data, snap)})["r1"], "daemon.json")


def test_a_list_setting_merges_into_the_options_list_and_a_value_replaces_it():
    from roles.docker import plan as docker_plan

    options = {"registry-mirrors": ["https://a.lan"], "ipv6": False}
    written = json.loads(
        docker_plan.daemon_json(
            options,
            {
                "registry-mirrors": ["https://b.lan", "https://a.lan"],
                "ipv6": True,
                "insecure-registries": [],
                "bip": None,
            },
        )
    )
    assert written == {"registry-mirrors": ["https://a.lan", "https://b.lan"], "ipv6": True}
