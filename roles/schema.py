"""The fleet file's JSON Schema, built from the checkers in roles/settings.py,
so an editor flags mistakes as the operator types (the checks before a run
stay the authority: cross-setting rules are not expressible here).

    python3 -m roles.schema > inventories/fleet.schema.json
"""

from __future__ import annotations

import json

from roles import fleet, settings


def setting_schemas(defaults: dict) -> dict:
    properties = {}
    for name, check in settings.SCHEMA.items():
        schema = dict(check.schema)
        if name in settings.YES_NO:
            schema = {"anyOf": [schema, {"enum": list(settings.YES_NO[name])}]}
        if name in defaults:
            schema["default"] = defaults[name]
        properties[name] = schema
    properties["address"] = {**settings.SCHEMA["ssh_hostname"].schema, "description": "the SSH address (ssh_hostname)"}
    return properties


def fleet_schema() -> dict:
    defaults = fleet.read_group_data().get("all", {})
    variables = {
        "type": ["object", "null"],
        "properties": setting_schemas(defaults),
        "additionalProperties": False,
    }
    group = {
        "type": ["object", "null"],
        "properties": {
            "vars": {"$ref": "#/definitions/settings"},
            "hosts": {
                "type": ["object", "null"],
                "propertyNames": {"pattern": f"^(?:{fleet.HOST_NAME.pattern})$"},
                "additionalProperties": {"$ref": "#/definitions/settings"},
            },
        },
        "additionalProperties": False,
    }
    return {
        "$schema": "http://json-schema.org/draft-07/schema#",
        "title": "Robot fleet file (inventories/robots.yaml)",
        "type": ["object", "null"],
        "properties": {
            "all": {
                "type": ["object", "null"],
                "properties": {"vars": {"$ref": "#/definitions/settings"}},
                "additionalProperties": False,
            },
            "robots": {"$ref": "#/definitions/group"},
            "laptops": {"$ref": "#/definitions/group"},
        },
        "patternProperties": {f"^{fleet.EXTENSION_PREFIX}": {}},
        "additionalProperties": False,
        "definitions": {"settings": variables, "group": group},
    }


def render() -> str:
    return json.dumps(fleet_schema(), indent=1, sort_keys=False) + "\n"


if __name__ == "__main__":
    print(render(), end="")
