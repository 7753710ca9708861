"""The docker role's users step: docker_users join the docker group.

Membership is appended (other groups untouched) and users are never created:
a declared user missing on the host fails that host.  The docker group is
root-equivalent; keep docker_users short.
"""

from __future__ import annotations

import shlex

from pyinfra import host
from pyinfra.api import deploy

from robotfleet.host import operations
from robotfleet.host.snapshot import SnapshotQuery
from robotfleet.role import Play


def declare_reads(data, query: SnapshotQuery) -> None:
    query.users |= set(data.docker_users)


def missing_memberships(users: list[str], groups_now: dict[str, list[str] | None]):
    """(users that do not exist, users to add to the docker group)."""
    absent = [u for u in users if groups_now.get(u) is None]
    to_add = [u for u in users if groups_now.get(u) is not None and "docker" not in groups_now[u]]
    return absent, to_add


@operations.operation()
def docker_group_members(users: list[str], groups_now: dict[str, list[str] | None]):
    absent, to_add = missing_memberships(users, groups_now)
    if absent:
        yield operations.refuse(
            f"docker_users: {', '.join(absent)} {'does' if len(absent) == 1 else 'do'} not exist on this host; "
            "create the account first (users are never created by this tool)"
        )
        return
    if not to_add:
        host.noop("docker group members in place")
        return
    yield operations.shell(" && ".join(f"usermod -aG docker {shlex.quote(u)}" for u in to_add))


@deploy("Users")
def docker_users(play: Play):
    docker_group_members(
        name="Add users to the docker group",
        users=play.data.docker_users,
        groups_now=play.snapshot.users,
    )
