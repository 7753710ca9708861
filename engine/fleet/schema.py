"""The fleet file's JSON Schema, built from the settings' checkers, so an
editor flags mistakes as the operator types (the checks before a run stay
the authority: rules across settings are not expressible here)."""

from __future__ import annotations

import json

from engine.fleet.check import EXTENSION_PREFIX, HOST_NAME
from engine.fleet.registry import Registry


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
        properties[alias] = {**registry.settings[name].check.schema, "description": f"the SSH address ({name})"}
    return properties


def fleet_schema(registry: Registry) -> dict:
    variables = {
        "type": ["object", "null"],
        "properties": setting_schemas(registry),
        "additionalProperties": False,
    }
    group = {
        "type": ["object", "null"],
        "properties": {
            "vars": {"$ref": "#/definitions/settings"},
            "hosts": {
                "type": ["object", "null"],
                "propertyNames": {"pattern": f"^(?:{HOST_NAME.pattern})$"},
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
        "patternProperties": {f"^{EXTENSION_PREFIX}": {}},
        "additionalProperties": False,
        "definitions": {"settings": variables, "group": group},
    }


def render(registry: Registry) -> str:
    return json.dumps(fleet_schema(registry), indent=1, sort_keys=False) + "\n"
