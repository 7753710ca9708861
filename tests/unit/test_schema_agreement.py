"""One source for the schema (issue 18, item 4): the editors' JSON Schema and
the run's checks are built from the same declarations, and give the same
verdict on the validation corpus and the hostile-value corpus wherever JSON
Schema can express the rule; docs/reference/fleet-file.md names the rules it cannot
(robotfleet/fleet/schema.py BEYOND_SCHEMA)."""

import json

import pytest

from robotfleet import deploy_roles
from robotfleet.checkers import Misread
from robotfleet.fleet import loader as fleetyaml
from robotfleet.fleet import schema as fleet_schema
from robotfleet.fleet import validate as fleet_check
from robotfleet.fleet.registry import Registry
from tests.fixtures import ROOT
from tests.unit import fleetcorpus, hostile

jsonschema = pytest.importorskip("jsonschema")

SCHEMA = fleet_schema.fleet_schema(deploy_roles.registry())
VALIDATOR = jsonschema.Draft7Validator(SCHEMA)
# What the schema says of one host's (or one group's vars') settings: the
# definition every place a setting sits refers to (test_a_setting_is_checked_alike_in_every_place).
SETTINGS = jsonschema.Draft7Validator({**SCHEMA["definitions"]["settings"], "definitions": SCHEMA["definitions"]})
MORE_VALUES = [
    "on",
    "off",
    "yes",
    "",
    " ",
    "fe80::1%eth0",
    "::ffff:10.0.0.1",
    "1::",
    "10.0.0.01",
    "robot-1.lan",
    "robot_1",
    "1.2.3",
    "x" * 64,
    "/var/lib/./tmp",
    "//tmp/x",
    "/var//tmp",
    "reg.example.com/p:1 2",
]
TRAPS = [fleetyaml.load(f"v: {trap}")["v"] for trap in hostile.YAML_TRAPS]


def schema_refuses(document) -> bool:
    return any(True for _ in VALIDATOR.iter_errors(document))


def json_only(value) -> bool:
    try:
        json.dumps(value, allow_nan=False)
    except (TypeError, ValueError):
        return False
    return not any(isinstance(item, Misread) for item in walk(value))


def walk(value):
    yield value
    if isinstance(value, dict):
        for key, item in value.items():
            yield key
            yield from walk(item)
    elif isinstance(value, list):
        for item in value:
            yield from walk(item)


def test_a_setting_is_checked_alike_in_every_place():
    """A group's vars, its hosts, its children's: each is the settings definition."""
    settings, group = {"$ref": "#/definitions/settings"}, SCHEMA["definitions"]["group"]
    assert group["properties"]["vars"] == settings
    assert group["properties"]["hosts"]["additionalProperties"] == settings
    assert group["properties"]["children"]["additionalProperties"] == {"$ref": "#/definitions/group"}
    assert SCHEMA["additionalProperties"] == {"$ref": "#/definitions/group"}
    for document in (
        {"robots": {"hosts": {"r1": {"ssh_port": "22"}}}},
        {"all": {"vars": {"ssh_port": "22"}}},
        {"robots": {"children": {"east": {"hosts": {"r1": {"ssh_port": "22"}}}}}},
    ):
        assert schema_refuses(document) and not SETTINGS.is_valid({"ssh_port": "22"}), document


@pytest.mark.parametrize("setting", sorted(deploy_roles.registry().settings))
def test_each_setting_gets_the_same_verdict_from_the_schema_and_the_run(setting):
    check = deploy_roles.registry().settings[setting].check
    disagree = []
    for value in [*hostile.HOSTILE, *MORE_VALUES, *TRAPS, 0, -1, 22, 70000, 1.5, True, None]:
        for place, placed in hostile.places(setting, value):
            if not json_only(placed):
                continue
            if bool(check(placed)) == SETTINGS.is_valid({setting: placed}):
                disagree.append((place, placed, check(placed)))
    assert disagree == []


class _NoRulesAcross(Registry):
    """The registry without the rules across settings (BEYOND_SCHEMA)."""

    def check_host(self, data, refused=frozenset()):
        return []


def expressible_lines(raw) -> list[str]:
    full = deploy_roles.registry()
    registry = _NoRulesAcross([], full.roles, full.aliases)
    registry.settings = full.settings
    try:
        fleet_check.check(raw, "f.yaml", registry)
    except fleet_check.FleetError as error:
        return [line for line in error.lines if "declared in both" not in line and "no hosts:" not in line]
    return []


def corpus_documents():
    for name, text, _ in fleetcorpus.CORPUS:
        if "billion" in name or name == "too large":
            continue  # jsonschema would walk every expanded alias
        try:
            raw = fleetyaml.load(text)
        except fleetyaml.YamlProblem:
            continue  # the editor shows YAML errors itself
        if json_only(raw):
            yield name, raw


@pytest.mark.parametrize("name, raw", list(corpus_documents()), ids=[name for name, _ in corpus_documents()])
def test_the_validation_corpus_gets_the_same_verdict(name, raw):
    lines = expressible_lines(raw)
    assert bool(lines) == schema_refuses(raw), (lines, [e.message for e in VALIDATOR.iter_errors(raw)])


def test_the_yaml_version_is_the_editors(tmp_path):
    """Unquoted on/yes are text to the editor and to the run: ROS_LOCALHOST_ONLY: on
    is accepted by both, x11_enabled: on refused by both."""
    base = "robots:\n  hosts:\n    r1:\n      payload_image: reg.example.com/p:1\n"
    for text, refused in (
        (base + "      payload_environment: {ROS_LOCALHOST_ONLY: on}\n", False),
        (base + "      x11_enabled: on\n", True),
    ):
        raw = fleetyaml.load(text)
        assert bool(expressible_lines(raw)) is refused and schema_refuses(raw) is refused, text


def test_the_fleet_file_doc_names_the_rules_the_schema_cannot_express():
    """docs/reference/fleet-file.md (README, "Describing a fleet", links it) lists them."""
    page = (ROOT / "docs" / "reference" / "fleet-file.md").read_text()
    assert "](docs/reference/fleet-file.md)" in (ROOT / "README.md").read_text()
    listed = page.split("these only the run checks:", 1)[1].split("\n## ", 1)[0]
    for rule in fleet_schema.BEYOND_SCHEMA:
        assert rule in listed, rule


def test_the_address_pattern_is_what_ipaddress_reads():
    """The schema's address pattern is the run's verdict: IPv4/IPv6 forms
    exactly as Python's ipaddress reads them (random and compressed forms)."""
    import ipaddress
    import random
    import re

    from robotfleet import value_kinds

    pattern = re.compile(f"(?:{value_kinds.IPV4}|{value_kinds.IPV6})", re.ASCII)
    rng = random.Random(7)
    for _ in range(20000):
        if rng.random() < 0.4:
            bits = rng.getrandbits(128) & ~((1 << rng.randrange(128)) - 1)
            text = rng.choice([str(ipaddress.IPv6Address(bits)), ipaddress.IPv6Address(bits).exploded])
            if rng.random() < 0.3 and text.count(":") >= 2:
                text = text.rsplit(":", 2)[0] + ":" + ".".join(str(rng.randrange(300)) for _ in range(4))
        else:
            text = "".join(rng.choice("0129:::..af%e") for _ in range(rng.randrange(1, 24)))
        try:
            ipaddress.ip_address(text)
            valid = True
        except ValueError:
            valid = False
        zone = text.partition("%")[2]
        if zone and not re.fullmatch(r"[0-9A-Za-z._~-]+", zone):
            valid = False  # a zone (%eth0) is an interface name: RFC 6874's unreserved characters
        assert bool(pattern.fullmatch(text)) == valid, text
