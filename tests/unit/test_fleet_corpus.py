"""The curated corpus: one broken fleet file per class of mistake (issue 9,
and the validator half of issue 8), each with the exact lines a user sees.
Every line names the file and the host/field; nothing else is printed."""

from pathlib import Path

import pytest

from tests.unit import harness as fleet
from tests.unit.fleetcorpus import CORPUS, host, lines


@pytest.mark.parametrize("text, expected", [c[1:] for c in CORPUS], ids=[c[0] for c in CORPUS])
def test_corpus(text, expected):
    assert lines(text) == expected


def test_accepted_yes_no_reads_as_the_documented_word():
    loaded = fleet.parse(host("ssh_strict_host_key_checking: no", "payload_restart_policy: no"), "f.yaml")
    ((name, data),) = loaded.hosts("robots")
    assert data["ssh_strict_host_key_checking"] == "no" and data["payload_restart_policy"] == "no"


def test_merge_keys_give_each_sensor_the_shared_fields_and_its_own():
    text = "x-camera: &camera {subsystem: video4linux, vendor_id: '046d', product_id: '0825', usb_port: '9-9'}\n"
    text += host("udev_sensors:", "  - {<<: *camera, name: front, usb_port: '1-1.2'}", "  - {<<: *camera, name: back}")
    ((_, data),) = fleet.parse(text, "f.yaml").hosts("robots")
    assert data["udev_sensors"] == [
        {"name": "front", "usb_port": "1-1.2", "subsystem": "video4linux", "vendor_id": "046d", "product_id": "0825"},
        {"name": "back", "subsystem": "video4linux", "vendor_id": "046d", "product_id": "0825", "usb_port": "9-9"},
    ]


def readme_mistakes():
    """The broken fleet file and the lines shown in docs/reference/fleet-file.md (linked
    from README's "Describing a fleet")."""
    section = (Path(__file__).resolve().parents[2] / "docs" / "reference" / "fleet-file.md").read_text()
    blocks = section.split("```")
    (fleet_block,) = [b for b in blocks if b.startswith("yaml\n") and "docker_usres" in b]
    (output_block,) = [b for b in blocks if "problem(s) in the fleet file" in b]
    (syntax_line,) = [line.strip() for line in section.splitlines() if ": YAML error: " in line]
    return fleet_block.removeprefix("yaml\n"), output_block.strip().splitlines(), syntax_line


def test_readme_shows_the_lines_the_common_mistakes_get():
    document, shown, syntax_line = readme_mistakes()
    try:
        fleet.parse(document, "inventories/robots.yaml")
    except fleet.FleetError as error:
        got = error.lines
    else:
        got = []
    assert got + [f"{len(got)} problem(s) in the fleet file; no host was contacted."] == shown
    unclosed = document.replace("serial: 42}", 'serial: "42"')
    assert lines_of(unclosed) == [syntax_line]


def lines_of(text: str) -> list[str]:
    try:
        fleet.parse(text, "inventories/robots.yaml")
    except fleet.FleetError as error:
        return error.lines
    return []


def test_without_libyaml_the_same_problems_are_found(monkeypatch):
    """Where PyYAML has no libyaml, its own parser is used: the wording of a
    syntax error may differ, the problems and their places do not."""
    import yaml

    from robotfleet.fleet import loader as fleetyaml

    # (5,000 levels of nesting only make PyYAML's recursive parser slow.)
    expected = {name: lines(text) for name, text, _ in CORPUS if name not in ("too large", "deep nesting")}
    monkeypatch.setattr(fleetyaml, "LOADER", yaml.SafeLoader)
    for name, text, _ in CORPUS:
        if name in expected:
            got = lines(text)
            where = [line.split(": YAML error: ")[0] if ": YAML error: " in line else line for line in got]
            want = [line.split(": YAML error: ")[0] if ": YAML error: " in line else line for line in expected[name]]
            assert where == want, name
