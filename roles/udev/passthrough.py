"""The sensors' devices in the payload's containers: which compose service
gets which device (added through the payload role's hook)."""

from __future__ import annotations

import roles.payload.hooks as payload_hooks
import roles.udev.rules as rules
import roles.udev.settings as settings
from robotfleet import checkers as c


def service_devices(data, services: dict[str, dict]) -> dict[str, list[str]]:
    """service -> device paths: a sensor goes to the services it names, by
    default to every service that asked for devices, or the single payload."""
    asking = [name for name, spec in services.items() if "devices" in spec]
    default = asking or (list(services) if len(services) == 1 else [])
    result: dict[str, list[str]] = {name: [] for name in services}
    for sensor in data.get("udev_sensors") or []:
        if not sensor.get("passthrough", True):
            continue
        for name in sensor.get("services") or default:
            if name in result:
                result[name].append(f"/dev/{rules.symlink(sensor)}")
    return result


def devices_for(data, services: dict[str, dict]) -> dict:
    """The payload hook: each service's devices, mapped at the same path."""
    return {
        name: {"devices": [f"{path}:{path}" for path in paths]}
        for name, paths in service_devices(data, services).items()
        if paths
    }


def problems(data: dict, refused: frozenset) -> list[c.Problem]:
    """Sensors that name a service the payload does not have, or that no
    service of a several-service payload would get (of the sensors that are
    valid on their own: one refused hides nothing of the others)."""
    services = payload_hooks.declared_services(data, refused)
    if not services:
        return []
    found = []
    asking = [name for name, spec in services.items() if "devices" in spec]
    sensors = data.get("udev_sensors")
    for index, sensor in enumerate(sensors if isinstance(sensors, list) else []):
        if not isinstance(sensor, dict) or not sensor.get("passthrough", True):
            continue
        if "udev_sensors" in refused and settings.sensor(sensor):
            continue
        named = sensor.get("services")
        for name in named or []:
            if name not in services:
                found.append(
                    (f"udev_sensors[{index}].services", f"no service called {name!r} (services: {', '.join(services)})")
                )
        if not named and len(services) > 1 and not asking:
            found.append(
                (
                    f"udev_sensors[{index}]",
                    "name the service(s) that use it (services: [...]); no service asks for devices",
                )
            )
    return found
