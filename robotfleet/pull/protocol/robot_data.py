"""A pull robot's data as both sides read it: the fleet file's host over
every default of its group (publish reads it to pin the release's images,
the robot's converge run to deploy it), and the settings that pin a
release's images on the robot."""

from __future__ import annotations

from pathlib import Path

from robotfleet import deploy_roles
from robotfleet.fleet.validate import FleetError, load
from robotfleet.pull.protocol import record as records


class DataError(Exception):
    """The robot's data cannot be read (one line)."""


class HostData(dict):
    """A host's merged fleet data, read as pyinfra's host data is (data.name)."""

    __getattr__ = dict.get


def host_data(robot: str, fleet_path: str | None, registry) -> HostData:
    """The robot's data as pyinfra sees it: every default, its group's, the
    fleet file's (a robot's defaults when no release told the fleet file yet)."""
    if fleet_path is None:
        return HostData({**deploy_roles.group_data("all"), **deploy_roles.group_data("robots")})
    try:
        fleet = load(Path(fleet_path), registry)
    except FleetError as error:
        raise DataError("; ".join(error.lines[:3])) from None
    for group in ("robots", "laptops"):
        for name, data in fleet.hosts(group):
            if name == robot:
                return HostData({**deploy_roles.group_data("all"), **deploy_roles.group_data(group), **data})
    raise DataError(f"{fleet_path}: no host named {robot!r}")


def pin_settings(roles, record: records.Record, robot: str) -> dict[str, dict[str, str]]:
    """The --data a robot's deploy runs with so it runs exactly the
    release's digests: each pinning role's setting -> the robot's pins."""
    return {role.pins.setting: record.images_of(robot) for role in roles if role.pins is not None}
