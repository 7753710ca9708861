"""The hostile-value corpus (issue 8): every setting, every place in it a
string can go, every hostile value.  Each is either refused with exactly one
line naming the host and the setting, or it is one of the few free-text
places, and then it is shown to reach the host as data: the compose file
(YAML), daemon.json (JSON) or a quoted udev match value, unchanged.

On-host quoting of the accepted values (e.g. compose's $ escaping) is tested
with the roles (tests/unit/test_onhost_plans.py, tests/integration/test_onhost_security.py);
here the validator's half: nothing else gets through.
"""

from __future__ import annotations

import json
from types import SimpleNamespace

import pytest
import yaml

from robotfleet.fleet import loader as fleetyaml
from roles.docker import plan
from roles.gpu import plan as gpu_plan
from roles.payload import compose
from roles.udev import rules
from tests.unit import harness as fleet
from tests.unit.hostile import HOSTILE, YAML_TRAPS, places

# YAML 1.1 traps that the fleet file, YAML 1.2, reads as the text written.
YAML_1_1_ONLY = ["NO", "off", "yes", "on", "12:30", "2026-01-02", "0b101", "1_000"]
DEFAULTS = fleet.group_data()

# Where a free-text value is accepted, and how it travels to the host.
CARRIED_AS_DATA = {
    ("payload_environment", "mapping value"): "compose",
    ("payload_command", "list item"): "compose",
    ("docker_daemon_options", "log-opts value"): "daemon.json",
    ("docker_daemon_options", "dns item"): "daemon.json",
    ("docker_daemon_options", "features key"): "daemon.json",
    ("docker_daemon_options", "builder value"): "daemon.json",
    ("udev_sensors", "serial"): "udev",
    # An argv payloadctl hands to `docker exec` (no shell), inside the container.
    ("gpu_check_command", "list item"): "argv",
}
# Text that is harmless where it lands: "/var/lib/" + "/tmp" is /var/lib/tmp,
# an absolute path never reads as an option, and in a URL's query ".." and
# "/" are just characters the server reads.
BENIGN_INSIDE = {
    "in a path": {"/tmp", "/var/tmp/x", "-rf", "--help"},
    "in a URL": {"..", "../../etc", "/var/lib/../../tmp", "/tmp", "/var/tmp/x", "-rf", "--help", "~root"},
}
# Files on the operator's machine, opened there by pyinfra; never sent to a host.
OPERATOR_SIDE = {
    "ssh_key",
    "ssh_known_hosts_file",
    "ssh_revoked_host_keys",
    "pull_wheelhouse",
    "pull_trust_root",
    "pull_remote_ca",
}
# ... and the values of these mappings (name -> a file here; its content is what is sent).
OPERATOR_SIDE_VALUES = {"payload_secret_files"}


def outcome(setting: str, value) -> list[str]:
    host = {"payload_image": "reg.example.com/p:1", setting: value}
    try:
        fleet.check({"robots": {"hosts": {"r1": host}}}, "f.yaml")
    except fleet.FleetError as error:
        return error.lines
    return []


def host_data(**settings_) -> SimpleNamespace:
    return SimpleNamespace(**{**DEFAULTS["all"], **DEFAULTS["robots"], **settings_})


def reaches_host_unchanged(setting: str, place: str, value, hostile: str) -> bool:
    carrier = CARRIED_AS_DATA[(setting, place)]
    if carrier == "compose":
        data = host_data(**{"payload_image": "reg.example.com/p:1", setting: value})
        text = compose.dump(compose.project(data, "10.0.0.1"))
        service = yaml.safe_load(text)["services"][compose.SERVICE]
        got = service["environment"]["X"] if setting == "payload_environment" else service["command"][0]
        return got.replace("$$", "$") == hostile  # compose reads $$ as $
    if carrier == "argv":
        data = {**DEFAULTS["all"], **DEFAULTS["robots"], "payload_gpu": True, setting: value}
        return gpu_plan.check_command(data)["command"] == [hostile]
    if carrier == "daemon.json":
        return json.loads(plan.daemon_json(value, {})) == value
    sensor = value[0]
    line = rules.rule(sensor)
    return f'ATTRS{{serial}}=="{hostile}"' in rules._split_items(line) or (
        f' ATTRS{{serial}}=="{hostile}"' in rules._split_items(line)
    )


@pytest.mark.parametrize("setting", list(fleet.setting_checks()))
def test_every_hostile_value_is_refused_in_one_line_or_reaches_the_host_as_data(setting):
    accepted = []
    for hostile in HOSTILE:
        for place, value in places(setting, hostile):
            lines = outcome(setting, value)
            if not lines:
                accepted.append((place, hostile))
                continue
            assert len(lines) == 1, (place, hostile, lines)
            assert lines[0].startswith(f"f.yaml: r1.{setting}"), (place, hostile, lines)
            assert "\n" not in lines[0] and "\r" not in lines[0] and "\x1b" not in lines[0]
    for place, hostile in accepted:
        if setting in OPERATOR_SIDE:
            assert place in ("value", "in a path", "in a URL", "in an image tag") and hostile.isprintable()
            continue
        if setting in OPERATOR_SIDE_VALUES:
            assert place == "mapping value" and hostile.isprintable(), (place, hostile)
            continue
        if hostile in BENIGN_INSIDE.get(place.removesuffix(", list item"), ()):
            continue
        if setting in ("payload_command", "gpu_check_command") or (
            setting == "payload_environment" and place == "mapping value"
        ):
            place = "list item" if setting != "payload_environment" else place  # any text: it is the container's
        assert (setting, place) in CARRIED_AS_DATA, f"{setting} ({place}) accepts {hostile!r}"
        value = dict(places(setting, hostile))[place]
        assert reaches_host_unchanged(setting, place, value, hostile), (setting, place, hostile)


def test_the_free_text_places_do_take_hostile_values():
    """The carriers above are exercised: shell-looking text is data there."""
    assert outcome("payload_environment", {"X": "$(touch /tmp/x)"}) == []
    assert outcome("payload_command", ["sh", "-c", "echo a; echo b"]) == []
    assert outcome("docker_daemon_options", {"log-opts": {"max-size": "`id`"}}) == []


def test_yaml_1_1_traps_are_the_text_written():
    doc = fleetyaml.load("".join(f"k{i}: {trap}\n" for i, trap in enumerate(YAML_1_1_ONLY)))
    assert list(doc.values()) == YAML_1_1_ONLY


# Refused as a secret is: the value never quoted, so no "read by YAML as" either.
SECRET_LINE = "expected the token payloadctl hold wrote (hex digits); the value is not shown"


@pytest.mark.parametrize("trap", YAML_TRAPS)
def test_yaml_traps_in_text_settings_say_quote_it(trap):
    """Unquoted, these are not the text written; every text setting refuses
    them with 'quote it', saying what YAML read (a secret's line shows no
    value).  ``~`` (null) is refused as nothing, except where null is the
    setting's own value (its default, or its doc says what null means)."""
    settings = fleet.registry().settings
    text_settings = [
        name
        for name, check in fleet.setting_checks().items()
        if check.schema.get("type") == "string" or "string" in json.dumps(check.schema)[:40]
    ]
    for name in text_settings:
        image = "" if name == "payload_image" else "      payload_image: reg.example.com/p:1\n"
        doc = fleetyaml.load(f"robots:\n  hosts:\n    r1:\n{image}      {name}: {trap}\n")
        setting = settings[name]
        null_is_a_value = setting.default is None or "null:" in setting.doc
        if trap == "~" and null_is_a_value and name != "payload_image":
            fleet.check(doc, "f.yaml")  # accepted: raises nothing
            assert doc["robots"]["hosts"]["r1"][name] is None
            continue
        with pytest.raises(fleet.FleetError) as raised:
            fleet.check(doc, "f.yaml")
        (line,) = [line for line in raised.value.lines if line.startswith(f"f.yaml: r1.{name}: ")]
        said = line[len(f"f.yaml: r1.{name}: ") :]
        if name == "payload_image" and trap == "~":
            assert said.startswith("required: "), line
        elif trap == "~":
            assert said.startswith("expected ") and said.endswith(", got nothing (null)"), line
        elif name == "payload_lock_token":
            assert said == SECRET_LINE, line
        else:
            read = "got a boolean (" if trap in ("true", "False") else f"got {trap} (read by YAML as "
            assert said.startswith("expected ") and read in said and said.endswith("); quote it"), line
