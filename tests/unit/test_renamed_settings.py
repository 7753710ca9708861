"""Settings renamed in issue 30 (item 7): each old name is still read as
the new one, with one note per layer that uses it; the old and the new name
in the same layer are refused in one line; the schema accepts the old names
marked deprecated and docs/reference/settings.md lists them."""

import json

import pytest

from robotfleet.commands import generate
from robotfleet.fleet import schema
from tests.fixtures import IMAGE
from tests.unit import harness as fleet
from tests.unit.harness import FleetError

# old name, new name, a value under the old name, the same under the new name
RENAMES = [
    ("display", "x11_enabled", "true", True),
    ("payload_lock_file", "payload_update_lock_path", "/var/lib/robot/update.lock", "/var/lib/robot/update.lock"),
    ("docker_restart_handler_state", "docker_daemon_config_change", "reloaded", "reload"),
    ("docker_restart_handler_state", "docker_daemon_config_change", "restarted", "restart"),
]


@pytest.fixture
def load(tmp_path):
    """Load fleet text from a file, as robotfleet does; problems and notes name it f.yaml."""
    path = tmp_path / "f.yaml"

    def loading(text: str):
        path.write_text(text)
        shown = fleet.display_path(path)
        try:
            loaded = fleet.load(path)
        except FleetError as error:
            raise FleetError([line.replace(shown, "f.yaml") for line in error.lines]) from None
        loaded.notes = [note.replace(shown, "f.yaml") for note in loaded.notes]
        return loaded
    return loading


def one_robot(*lines: str) -> str:
    host = "".join(f"      {line}\n" for line in lines)
    return f"robots:\n  hosts:\n    r1:\n      address: 10.0.0.3\n      payload_image: {IMAGE}\n{host}"


def test_every_rename_is_declared_and_tested():
    declared = {(old, r.new) for old, r in fleet.registry().renamed.items()}
    assert declared == {(old, new) for old, new, _, _ in RENAMES}


@pytest.mark.parametrize("old, new, written, value", RENAMES)
def test_an_old_name_still_works_with_a_note(old, new, written, value, load):
    extra = ["x11_user: alice"] if new == "x11_enabled" else []
    loaded = load(one_robot(*extra, f"{old}: {written}"))
    data = dict(loaded.hosts("robots"))["r1"]
    assert data[new] == value and old not in data
    assert loaded.notes == [f"f.yaml: note: r1: {old} is now {new}; the old name still works (rename it)"]


def test_an_inventory_with_lines_names_the_line(tmp_path):
    """INI inventories have lines (YAML fleet lines name the file only, as every problem does)."""
    path = tmp_path / "hosts"
    path.write_text(f"[robots]\nr0 address=10.0.0.2 payload_image={IMAGE}\n"
                    f"r1 address=10.0.0.3 payload_image={IMAGE} display=True x11_user=alice\n")
    loaded = fleet.load(path)
    assert dict(loaded.hosts("robots"))["r1"]["x11_enabled"] is True
    assert loaded.notes == [f"{fleet.display_path(path)}:3: note: r1: display is now x11_enabled; "
                            "the old name still works (rename it)"]


def test_the_new_name_takes_no_note(load):
    loaded = load(one_robot("docker_daemon_config_change: reload"))
    assert dict(loaded.hosts("robots"))["r1"]["docker_daemon_config_change"] == "reload"
    assert loaded.notes == []


@pytest.mark.parametrize("old, new, written, value", RENAMES[:3])
def test_the_old_and_the_new_name_in_one_place_are_refused_in_one_line(old, new, written, value, load):
    new_written = json.dumps(value)
    with pytest.raises(FleetError) as error:
        load(one_robot(f"{new}: {new_written}", f"{old}: {written}"))
    assert error.value.lines == [f"f.yaml: r1.{old}: {old} is the old name of {new}, set here too; keep {new}"]


def test_one_note_per_layer_and_the_later_layer_wins_across_names(load):
    text = ("all:\n  vars:\n    display: true\n    x11_user: alice\n"
            f"robots:\n  hosts:\n    r1:\n      address: 10.0.0.3\n      payload_image: {IMAGE}\n"
            "      x11_enabled: false\n"
            f"    r2:\n      address: 10.0.0.4\n      payload_image: {IMAGE}\n")
    loaded = load(text)
    hosts = dict(loaded.hosts("robots"))
    assert hosts["r1"]["x11_enabled"] is False and hosts["r2"]["x11_enabled"] is True
    assert loaded.notes == ["f.yaml: note: all.vars: display is now x11_enabled; the old name still works (rename it)"]


def test_an_old_name_keeps_its_own_values(load):
    with pytest.raises(FleetError) as error:
        load(one_robot("docker_restart_handler_state: reload"))
    assert error.value.lines == ["f.yaml: r1.docker_restart_handler_state: expected one of restarted, reloaded, "
                                 "got 'reload'"]
    with pytest.raises(FleetError) as error:
        load(one_robot("display: yes"))
    assert error.value.lines == ["f.yaml: r1.display: expected true or false, got 'yes'"]


def test_the_rules_read_an_old_name_as_the_new_one():
    assert fleet.fleet_problems({"robots": {"hosts": {"r1": {"address": "10.0.0.3", "payload_image": IMAGE,
                                                               "display": True}}}}) == [
        "robots.yaml: r1.x11_user: required when x11_enabled is true: the desktop user"]


@pytest.mark.parametrize("written, action", [("reloaded", "reload"), ("restarted", "restart")])
def test_the_old_value_reaches_the_role_as_the_new_one(written, action, load):
    """docker_restart_handler_state: reloaded still reloads Docker after a daemon.json change."""
    data = dict(load(one_robot(f"docker_restart_handler_state: {written}")).hosts("robots"))["r1"]
    data = {**fleet.ROBOT, **{k: v for k, v in data.items() if k != "address"}}
    commands = fleet.plan({"r1": ("robots", data, fleet.fresh_host("debian-13"))})["r1"]
    applied = fleet.find(commands, "systemctl .* docker.service >/dev/null")
    assert applied and all(f"systemctl {action} docker.service" in c for c in applied)


def test_the_schema_accepts_the_old_names_marked_deprecated():
    properties = json.loads(schema.render(fleet.registry()))["definitions"]["settings"]["properties"]
    for old, new, _, _ in RENAMES:
        assert properties[old]["deprecated"] is True
        assert properties[old]["description"].startswith(f"Deprecated: {old} is now {new}")
    assert properties["docker_restart_handler_state"]["enum"] == ["restarted", "reloaded"]
    assert properties["docker_daemon_config_change"]["enum"] == ["restart", "reload"]
    assert "deprecated" not in properties["x11_enabled"]


def test_the_settings_table_lists_the_renames():
    text = generate.settings_doc(fleet.registry())
    renamed = text[text.index("## Renamed settings"):]
    assert "| `display` | `x11_enabled` | the same |" in renamed
    assert "| `payload_lock_file` | `payload_update_lock_path` | the same |" in renamed
    assert ("| `docker_restart_handler_state` | `docker_daemon_config_change` | "
            "`restarted` is now `restart`, `reloaded` is now `reload` |") in renamed
