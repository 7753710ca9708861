"""The payload's compose services as the fleet file declares them (pure).

- ``merge_values``: group and host ``payload_services`` merge per service and
  per key (a host restates only what differs; ``null`` removes a service or
  a key), the way users of Ansible's ``combine(recursive=True)`` expect.
- ``declared``: the services a host runs (``payload_services``, or the
  single-image shorthand as one service called ``payload``).
- ``service``: one service of the compose document, our defaults under the
  user's keys.
"""

from __future__ import annotations

import copy
import json
import re

import roles.payload.payloadctl.imageref as imageref
from robotfleet.checkers import key_name

SHORTHAND = "payload"
SERVICE_NAME = r"[a-zA-Z0-9][a-zA-Z0-9._-]*"
# The settings that only describe the shorthand's one service.
SHORTHAND_SETTINGS = {"payload_command": None, "payload_volumes": [], "payload_gpu": False, "payload_platform": None}


# --- merging ----------------------------------------------------------------


def merge(base, override):
    """Mappings merge recursively, None removes a key, anything else replaces."""
    if not isinstance(base, dict) or not isinstance(override, dict):
        return copy.deepcopy(override)
    result = copy.deepcopy(base)
    for key, value in override.items():
        if value is None:
            result.pop(key, None)
        else:
            result[key] = merge(result.get(key), value)
    return result


def merge_values(values: list) -> dict:
    """payload_services of all.vars < group vars < host, merged per service."""
    merged: dict = {}
    for value in values:
        if isinstance(value, dict):
            merged = merge(merged, value)
    return merged


def merge_layers(layers: list) -> dict:
    return merge_values([(layer or {}).get("payload_services") for layer in layers])


# --- the services a host runs --------------------------------------------------


def value_of(data, key, default=None):
    """A setting from pyinfra host data or a plain dict; None reads as ``default``."""
    getter = getattr(data, "get", None)
    value = getter(key, default) if getter else getattr(data, key, default)
    return default if value is None and default is not None else value


def declared(data) -> dict[str, dict]:
    """name -> the service as the user wrote it (before our defaults)."""
    services = value_of(data, "payload_services") or {}
    if services:
        return {name: dict(spec or {}) for name, spec in services.items()}
    image = value_of(data, "payload_image")
    if not image:
        return {}
    platform = value_of(data, "payload_platform")
    return {SHORTHAND: {"image": image, **({"platform": platform} if platform else {})}}


def environment_mapping(value) -> dict:
    """Compose's environment, list form ("A=1") or mapping, as a mapping."""
    if isinstance(value, dict):
        return dict(value)
    result = {}
    for item in value or []:
        key, sep, rest = str(item).partition("=")
        result[key] = rest if sep else None
    return result


# --- one service of the document ------------------------------------------------


def _unique(items: list) -> list:
    seen, result = set(), []
    for item in items:
        key = json.dumps(item, sort_keys=True)
        if key not in seen:
            seen.add(key)
            result.append(item)
    return result


def service(base: dict, user: dict, extra: dict, name: str) -> dict:
    """``base`` is the single-service builder's result (restart, network,
    ROS/X11 environment, label, sensors); the preset and the user's keys go
    on top: environment and labels merge, volumes and devices add up, any
    other key of the user's replaces ours."""
    result = copy.deepcopy(base)
    env = result.get("environment", {})
    for key in extra["drop"]:
        env.pop(key, None)
    env.update(extra["environment"])
    env.update(environment_mapping(user.get("environment")))
    result["environment"] = env
    # Compose's labels, like its environment, may be a list of "key=value".
    result["labels"] = {**environment_mapping(user.get("labels")), **extra["labels"], **result.get("labels", {})}
    volumes = list(user.get("volumes") or []) + result.get("volumes", []) + extra["volumes"]
    devices = list(user.get("devices") or []) + result.get("devices", [])
    for key, value in user.items():
        if key not in ("environment", "labels", "volumes", "devices"):
            result[key] = copy.deepcopy(value)
    for key, value in extra["keys"].items():
        if key == "depends_on":
            if name not in extra["extra"]:
                result[key] = depends_on(user.get(key), value)
        elif key not in user:
            result[key] = copy.deepcopy(value)
    for key in extra.get("unset", []):
        if key not in user:
            result.pop(key, None)
    if volumes:
        result["volumes"] = _unique(volumes)
    if devices:
        result["devices"] = _unique(devices)
    else:
        result.pop("devices", None)
    return result


def depends_on(own, added: dict) -> dict:
    """A service's own depends_on (a list of names or compose's long form)
    with ``added`` (long form): a dependency the service names itself is its own."""
    if isinstance(own, list):
        own = {str(name): {"condition": "service_started"} for name in own}
    return {**copy.deepcopy(added), **copy.deepcopy(own or {})} if isinstance(own, (dict, type(None))) else own


def platforms(data) -> dict[str, str]:
    """service -> the platform it pins (Compose's ``platform`` key)."""
    return {name: spec["platform"] for name, spec in declared(data).items() if isinstance(spec.get("platform"), str)}


def images(data) -> list[str]:
    """Every image the project runs (the preset's roscore included)."""
    refs = [spec.get("image") for spec in declared(data).values()]
    if value_of(data, "ros_preset") == "ros1" and value_of(data, "ros_roscore"):
        refs.append(value_of(data, "ros_roscore_image"))
    return [r for r in dict.fromkeys(refs) if isinstance(r, str)]


def primary_image(data) -> str | None:
    """The image whose registry the login is for (the first service's)."""
    refs = images(data)
    return refs[0] if refs else None


def repositories(data) -> list[str]:
    result = []
    for ref in images(data):
        try:
            result.append(imageref.parse(ref).repository)
        except ValueError:
            continue
    return sorted(set(result))


def layer_problems(value) -> list[tuple[str, str]]:
    """One layer's payload_services: a mapping of service name -> mapping (or
    null to remove it).  Keys are checked on the merged project."""
    if not isinstance(value, dict):
        return [("", "expected a mapping of service name -> compose service")]
    problems = []
    for name, spec in value.items():
        if not isinstance(name, str) or not re.fullmatch(SERVICE_NAME, name):
            problems.append(
                (f".{key_name(name)}", "service names are letters, digits, . _ - (starting with a letter or digit)")
            )
        elif spec is not None and not isinstance(spec, dict):
            problems.append(
                (f".{key_name(name)}", "expected a mapping of compose keys (or null to remove the service)")
            )
    return problems
