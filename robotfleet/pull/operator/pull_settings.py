"""Pull mode's settings of a host, as the operator's commands read them:
through the pull part of deploy.py's roles (robotfleet/role.py ``PullPart``,
given by roles/pull), never by a setting's name."""

from __future__ import annotations

from robotfleet import deploy_roles
from robotfleet.role import PullPart, pull_part


def part() -> PullPart:
    return pull_part(deploy_roles.roles())


def pulls(data) -> bool:
    """Whether a host with ``data`` converges itself from signed releases."""
    return part().pulls(data)
