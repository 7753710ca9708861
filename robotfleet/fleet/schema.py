"""The fleet file's JSON Schema, built from the settings' checkers (each
checker carries the schema of what it accepts, from the same patterns), so
an editor flags mistakes as the operator types and agrees with the run
(tests/unit/test_schema_agreement.py).  What the schema cannot say is
BEYOND_SCHEMA; the run checks it, and docs/reference/fleet-file.md names it."""

from __future__ import annotations

import json

from robotfleet.fleet.connection import OLDER_NAMES
from robotfleet.fleet.registry import Registry
from robotfleet.fleet.validate import ANSIBLE_PREFIX, EXTENSION_PREFIX, HOST_NAME

# The rules only the run checks, each with what docs/reference/fleet-file.md says of it.
BEYOND_SCHEMA = {
    "rules across settings": "each role's rules on a host's merged settings: x11_user when x11_enabled is true, "
    "a pinned payload image, sensors that would match the same device, ros_roscore with ros_preset: ros1, "
    "a TCP listener in docker_daemon_options without TLS client verification, a registry credential file "
    "inside the checkout",
    "a host in two groups": "a host declared under both robots and laptops, or in groups of both kinds",
    "a host of no kind": "a host in neither a robots nor a laptops group (at any depth)",
    "a fleet with no hosts": "a file that declares no host at all",
    "respelled numbers": "a number written so that YAML changes it (0022, 1.10, 0x1F) where a number is "
    "expected: the schema sees only the number",
    "expanded size": "docker_daemon_options of more than 10000 values once YAML aliases are expanded",
}


def setting_schemas(registry: Registry) -> dict:
    defaults = registry.defaults()
    properties = {}
    for name, setting in registry.settings.items():
        schema = dict(setting.check.schema)
        kind = schema.get("description")
        schema["description"] = setting.doc + (f" Expected: {kind}." if kind else "")
        if name in defaults:
            schema["default"] = defaults[name]
        properties[name] = schema
    for alias, name in registry.aliases.items():
        if alias in OLDER_NAMES:
            doc = f"Ansible's older name for {name}: where both are set, it wins, as in Ansible."
        elif alias.startswith(ANSIBLE_PREFIX):
            doc = f"Ansible's name for {name}."
        else:
            doc = f"{name}: {registry.settings[name].doc}"
        properties[alias] = {**registry.settings[name].check.schema, "description": doc}
    for old, rename in registry.renamed.items():
        properties[old] = {
            **registry.old_check(rename).schema,
            "deprecated": True,
            "description": f"Deprecated: {renamed_line(rename)}. {registry.settings[rename.new].doc}",
        }
    return properties


def renamed_line(rename) -> str:
    """``display is now x11_enabled`` (with the values the new name takes for the old ones)."""
    values = ", ".join(f"{old} is now {new}" for old, new in rename.values.items())
    return f"{rename.old} is now {rename.new}" + (f" ({values})" if values else "") + "; the old name still works"


def fleet_schema(registry: Registry) -> dict:
    variables = {
        "type": ["object", "null"],
        "properties": setting_schemas(registry),
        # Ansible's own variables (ansible_become, ...) are ignored by the run.
        "patternProperties": {f"^{ANSIBLE_PREFIX}": {}},
        "additionalProperties": False,
    }
    name = {"pattern": f"^(?:{HOST_NAME.pattern})$"}
    # Ansible's host patterns: robot[01:03], robot[a:c], robot[1:9:2], robot7:2222
    ranged = r"\[(?:[0-9]*:[0-9]+|[A-Za-z]:[A-Za-z])(?::[0-9]+)?\]"
    host = {"anyOf": [name, {"pattern": f"^(?:[A-Za-z0-9]|{ranged})(?:[A-Za-z0-9._-]|{ranged})*(?::[0-9]+)?$"}]}
    group = {
        "type": ["object", "null"],
        "properties": {
            "vars": {"$ref": "#/definitions/settings"},
            "hosts": {
                "type": ["object", "null"],
                "propertyNames": host,
                "additionalProperties": {"$ref": "#/definitions/settings"},
            },
            "children": {
                "type": ["object", "null"],
                "propertyNames": name,
                "additionalProperties": {"$ref": "#/definitions/group"},
            },
        },
        "additionalProperties": False,
    }
    return {
        "$schema": "http://json-schema.org/draft-07/schema#",
        "title": "Robot fleet file (inventories/robots.yaml): an Ansible-style YAML inventory",
        "type": ["object", "null"],
        "propertyNames": {"anyOf": [name, {"pattern": f"^{EXTENSION_PREFIX}"}]},
        "patternProperties": {f"^{EXTENSION_PREFIX}": {}},
        "additionalProperties": {"$ref": "#/definitions/group"},
        "definitions": {"settings": variables, "group": group},
    }


def render(registry: Registry) -> str:
    return json.dumps(fleet_schema(registry), indent=1, sort_keys=False) + "\n"
