"""The shipped JSON Schema of the fleet file (for editors) is current, valid,
and never flags a fleet the checks accept."""

import json

import pytest

from robotfleet.commands import generate
from robotfleet.fleet import loader as fleetyaml
from tests.fixtures import ROOT
from tests.unit import fleetcorpus, fleetfuzz

jsonschema = pytest.importorskip("jsonschema")

SHIPPED = ROOT / "inventories" / "fleet.schema.json"


@pytest.fixture(scope="module")
def validator():
    shipped = json.loads(SHIPPED.read_text())
    jsonschema.Draft7Validator.check_schema(shipped)
    return jsonschema.Draft7Validator(shipped)


def test_shipped_schema_is_generated_from_the_checks():
    assert SHIPPED.read_text() == generate.generated()[SHIPPED], "run: robotfleet generate"


def test_example_fleet_wires_the_schema_for_editors():
    first = (ROOT / "inventories" / "robots.yaml").read_text().splitlines()[0]
    assert first == "# yaml-language-server: $schema=fleet.schema.json"


def test_schema_flags_the_common_mistakes(validator):
    doc = {
        "robots": {
            "hosts": {
                "r1": {
                    "docker_usres": [],
                    "ssh_port": "22",
                    "payload_dir": "/tmp/p",
                    "udev_sensors": [{"name": "cam", "subsystem": "camera", "serial": "1"}],
                }
            }
        }
    }
    paths = sorted(".".join(map(str, error.absolute_path)) for error in validator.iter_errors(doc))
    assert paths == [
        "robots.hosts.r1",
        "robots.hosts.r1.payload_dir",
        "robots.hosts.r1.ssh_port",
        "robots.hosts.r1.udev_sensors.0.subsystem",
    ]


def accepted_documents():
    for _, text, expected in fleetcorpus.CORPUS:
        if not expected:
            yield text if isinstance(text, bytes) else text.encode()
    for _, data in fleetfuzz.documents(22, 100, seed=4):
        if fleetfuzz.outcome(data) is None:
            yield data
    yield (ROOT / "inventories" / "robots.yaml").read_bytes()


def test_schema_accepts_every_fleet_the_checks_accept(validator):
    count = 0
    for data in accepted_documents():
        errors = [error.message for error in validator.iter_errors(fleetyaml.load(data))]
        assert errors == [], data
        count += 1
    assert count > 10
