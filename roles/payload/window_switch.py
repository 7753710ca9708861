"""The payload's part in a pull robot's prepared switch (robotfleet.role
SwitchPart): before the maintenance window, the release the planning run
wrote is made ready with `payloadctl prepare` (images present, the release
written and checked, nothing that runs touched); in the window,
`payloadctl switch` runs it under the same health gate and rollback as an
apply."""

from __future__ import annotations

from robotfleet.role import SwitchPart
from roles.payload.installed_files import HELPER
from roles.payload.release import read_result

SETTING = "payload_switch_request"


def prepare_command(data, request_file: str) -> list[str]:
    return ["/usr/bin/python3", HELPER, "prepare", request_file]


def switch_command(data, prepared: str, deployment: str) -> list[str]:
    return [
        "/usr/bin/python3",
        HELPER,
        "switch",
        "--dir",
        data.payload_dir,
        "--release",
        prepared,
        "--by",
        "pull agent",
        "--deployment",
        deployment,
    ]


def read(stdout: str) -> dict | None:
    """payloadctl's result line: ok, outcome, target and its line for people."""
    found = read_result(stdout.splitlines())
    if found is None:
        return None
    return {key: found.get(key) for key in ("ok", "outcome", "target", "message")}


SWITCH = SwitchPart(setting=SETTING, prepare=prepare_command, switch=switch_command, read=read)
