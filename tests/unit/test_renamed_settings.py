"""Settings renamed in issue 30 (item 7) and issue 37 (item 4): each old
name is still read as the new one, with one note per layer that uses it; the old and the new name
in the same layer are refused in one line; the schema accepts the old names
marked deprecated and docs/reference/settings.md lists them."""

import base64
import json

import pytest

from robotfleet.commands import generate
from robotfleet.fleet import schema
from robotfleet.pull.operator import publishing
from roles import gpu
from tests.fixtures import IMAGE
from tests.unit import harness as fleet
from tests.unit.harness import FleetError, fresh_host

NVRM = "NVRM version: NVIDIA UNIX x86_64 Kernel Module  550.54.14  Thu Feb 22 01:44:30 UTC 2024"

SENSOR = {"name": "imu", "subsystem": "tty", "serial": "A1"}
# old name, new name, a value under the old name, the same under the new name
RENAMES = [
    ("display", "x11_enabled", "true", True),
    ("pull", "pull_enabled", "true", True),
    ("gpu", "gpu_vendor", "nvidia", "nvidia"),
    ("sensors", "udev_sensors", json.dumps([SENSOR]), [SENSOR]),
    ("payload_lock_file", "payload_update_lock_path", "/var/lib/robot/update.lock", "/var/lib/robot/update.lock"),
    ("docker_restart_handler_state", "docker_daemon_config_change", "reloaded", "reload"),
    ("docker_restart_handler_state", "docker_daemon_config_change", "restarted", "restart"),
]
ONCE = [rename for i, rename in enumerate(RENAMES) if rename[0] not in {old for old, *_ in RENAMES[:i]}]
# What a host needs beside the new name for the rules to pass.
NEEDS = {"x11_enabled": ["x11_user: alice"], "pull_enabled": ["pull_remote: https://git.lan/fleet.git"]}


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
    loaded = load(one_robot(*NEEDS.get(new, []), f"{old}: {written}"))
    data = dict(loaded.hosts("robots"))["r1"]
    assert data[new] == value and old not in data
    assert loaded.notes == [f"f.yaml: note: r1: {old} is now {new}; the old name still works (rename it)"]


def test_an_inventory_with_lines_names_the_line(tmp_path):
    """INI inventories have lines (YAML fleet lines name the file only, as every problem does)."""
    path = tmp_path / "hosts"
    path.write_text(
        f"[robots]\nr0 address=10.0.0.2 payload_image={IMAGE}\n"
        f"r1 address=10.0.0.3 payload_image={IMAGE} display=True x11_user=alice\n"
    )
    loaded = fleet.load(path)
    assert dict(loaded.hosts("robots"))["r1"]["x11_enabled"] is True
    assert loaded.notes == [
        f"{fleet.display_path(path)}:3: note: r1: display is now x11_enabled; the old name still works (rename it)"
    ]


def test_the_new_name_takes_no_note(load):
    loaded = load(one_robot("docker_daemon_config_change: reload"))
    assert dict(loaded.hosts("robots"))["r1"]["docker_daemon_config_change"] == "reload"
    assert loaded.notes == []


@pytest.mark.parametrize("old, new, written, value", ONCE)
def test_the_old_and_the_new_name_in_one_place_are_refused_in_one_line(old, new, written, value, load):
    new_written = json.dumps(value)
    with pytest.raises(FleetError) as error:
        load(one_robot(f"{new}: {new_written}", f"{old}: {written}"))
    assert error.value.lines == [f"f.yaml: r1.{old}: {old} is the old name of {new}, set here too; keep {new}"]


# old name, new name, a value written under each name in YAML, the two values as read
ACROSS = [
    ("display", "x11_enabled", "true", "false", True, False),
    ("pull", "pull_enabled", "true", "false", True, False),
    ("gpu", "gpu_vendor", "nvidia", "null", "nvidia", None),
    ("sensors", "udev_sensors", json.dumps([SENSOR]), "[]", [SENSOR], []),
]


@pytest.mark.parametrize("old, new, old_written, new_written, old_value, new_value", ACROSS)
def test_one_note_per_layer_and_the_later_layer_wins_across_names(
    old, new, old_written, new_written, old_value, new_value, load
):
    """The group sets the old name, one host the new: the host's wins there, the group's elsewhere."""
    needs = "".join(f"    {line}\n" for line in NEEDS.get(new, []))
    text = (
        f"all:\n  vars:\n    {old}: {old_written}\n{needs}"
        f"robots:\n  hosts:\n    r1:\n      address: 10.0.0.3\n      payload_image: {IMAGE}\n"
        f"      {new}: {new_written}\n"
        f"    r2:\n      address: 10.0.0.4\n      payload_image: {IMAGE}\n"
    )
    loaded = load(text)
    hosts = dict(loaded.hosts("robots"))
    assert hosts["r1"][new] == new_value and hosts["r2"][new] == old_value
    assert old not in hosts["r1"] and old not in hosts["r2"]
    assert loaded.notes == [f"f.yaml: note: all.vars: {old} is now {new}; the old name still works (rename it)"]


@pytest.mark.parametrize("old, new, old_written, new_written, old_value, new_value", ACROSS)
def test_a_host_s_old_name_wins_over_its_group_s_new_name(
    old, new, old_written, new_written, old_value, new_value, load
):
    needs = "".join(f"    {line}\n" for line in NEEDS.get(new, []))
    text = (
        f"all:\n  vars:\n    {new}: {new_written}\n{needs}"
        f"robots:\n  hosts:\n    r1:\n      address: 10.0.0.3\n      payload_image: {IMAGE}\n"
        f"      {old}: {old_written}\n"
    )
    loaded = load(text)
    assert dict(loaded.hosts("robots"))["r1"][new] == old_value
    assert loaded.notes == [f"f.yaml: note: r1: {old} is now {new}; the old name still works (rename it)"]


def test_an_old_name_keeps_its_own_values(load):
    with pytest.raises(FleetError) as error:
        load(one_robot("docker_restart_handler_state: reload"))
    assert error.value.lines == [
        "f.yaml: r1.docker_restart_handler_state: expected one of restarted, reloaded, got 'reload'"
    ]
    with pytest.raises(FleetError) as error:
        load(one_robot("display: yes"))
    assert error.value.lines == ["f.yaml: r1.display: expected true or false, got 'yes'"]


def test_the_rules_read_an_old_name_as_the_new_one():
    assert fleet.fleet_problems(
        {"robots": {"hosts": {"r1": {"address": "10.0.0.3", "payload_image": IMAGE, "display": True}}}}
    ) == ["robots.yaml: r1.x11_user: required when x11_enabled is true: the desktop user"]
    assert fleet.fleet_problems(
        {"robots": {"hosts": {"r1": {"address": "10.0.0.3", "payload_image": IMAGE, "pull": True}}}}
    ) == [
        "robots.yaml: r1.pull_remote: required when pull_enabled is true: the git URL of the fleet remote "
        "(e.g. ssh://gitolite3@git.example.com/fleet)"
    ]
    twins = [SENSOR, {**SENSOR, "serial": "B2", "symlink": "imu2"}]
    assert fleet.fleet_problems(
        {"robots": {"hosts": {"r1": {"address": "10.0.0.3", "payload_image": IMAGE, "sensors": twins}}}}
    ) == ["robots.yaml: r1.udev_sensors[1].name: duplicate sensor name 'imu' (also udev_sensors[0])"]


@pytest.mark.parametrize("written, action", [("reloaded", "reload"), ("restarted", "restart")])
def test_the_old_value_reaches_the_role_as_the_new_one(written, action, load):
    """docker_restart_handler_state: reloaded still reloads Docker after a daemon.json change."""
    data = dict(load(one_robot(f"docker_restart_handler_state: {written}")).hosts("robots"))["r1"]
    data = {**fleet.ROBOT, **{k: v for k, v in data.items() if k != "address"}}
    commands = fleet.plan({"r1": ("robots", data, fleet.fresh_host("debian-13"))})["r1"]
    applied = fleet.find(commands, "systemctl .* docker.service >/dev/null")
    assert applied and all(f"systemctl {action} docker.service" in c for c in applied)


def gpu_host():
    snap = fresh_host("ubuntu-24.04")
    snap.probes[gpu.READINGS] = f"driver={base64.b64encode(NVRM.encode()).decode()}\nsmi_rc=0\nsmi=R1BV\n"
    return snap


@pytest.mark.parametrize(
    "old, new, written, fresh, role_s",
    [
        ("gpu", "gpu_vendor", "nvidia", gpu_host, "nvidia-container-toolkit"),
        ("sensors", "udev_sensors", json.dumps([SENSOR]), lambda: fresh_host("debian-13"), "70-robot-sensors.rules"),
    ],
)
def test_an_old_name_reaches_its_role_as_the_new_one(old, new, written, fresh, role_s, load):
    """gpu: nvidia still installs the toolkit, sensors still writes the rules: the very commands of the new name."""
    sent = {}
    for name in (old, new, None):
        data = dict(load(one_robot(*([f"{name}: {written}"] if name else []))).hosts("robots"))["r1"]
        data = {
            **{k: v for k, v in fleet.ROBOT.items() if k != "udev_sensors"},
            **{k: v for k, v in data.items() if k != "address"},
        }
        sent[name] = [
            (str(c), str(c.stdin)) for c in fleet.find(fleet.plan({"r1": ("robots", data, fresh())})["r1"], role_s)
        ]
    assert sent[old] and sent[old] == sent[new] and not sent[None]


def test_pull_reaches_the_engine_as_pull_enabled(load):
    """publish, status and bundle read the pull hosts through the pull role: an old pull: true is one."""
    loaded = load(
        "robots:\n  vars: {pull: true, pull_remote: 'https://git.lan/fleet.git'}\n  hosts:\n"
        f"    r1: {{address: 10.0.0.3, payload_image: {IMAGE}}}\n"
        f"    r2: {{address: 10.0.0.4, payload_image: {IMAGE}, pull: false}}\n"
    )
    assert [name for name, _ in publishing.pull_hosts(loaded, fleet.registry())] == ["r1"]


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
    renamed = text[text.index("## Renamed settings") :]
    assert "| `display` | `x11_enabled` | the same |" in renamed
    assert "| `payload_lock_file` | `payload_update_lock_path` | the same |" in renamed
    assert "| `pull` | `pull_enabled` | the same |" in renamed
    assert "| `gpu` | `gpu_vendor` | the same |" in renamed
    assert "| `sensors` | `udev_sensors` | the same |" in renamed
    assert (
        "| `docker_restart_handler_state` | `docker_daemon_config_change` | "
        "`restarted` is now `restart`, `reloaded` is now `reload` |"
    ) in renamed
