"""The roles deploy.py lists, and what the engine builds from them.

deploy.py is the one list of roles.  Everything else that needs them (the
fleet check in inventories/, group_data/, the schema for editors, status and
rollout) reads that list here: deploy.py is run the way pyinfra runs it, but
with no host, so ``robotfleet.provision.provision`` only hands back the list.
"""

from __future__ import annotations

import contextvars
import functools
import runpy
from pathlib import Path

from robotfleet import CHECKOUT
from robotfleet.fleet import connection, pull_mode
from robotfleet.fleet.registry import Registry
from robotfleet.role import Role, cards

DEPLOY = CHECKOUT / "deploy.py"
_reading = contextvars.ContextVar("reading deploy.py for its roles", default=False)


def reading() -> bool:
    """True while deploy.py runs only to name its roles."""
    return _reading.get()


@functools.lru_cache(maxsize=4)
def roles(deploy_file: Path = DEPLOY) -> tuple[Role, ...]:
    """The roles ``deploy_file`` lists (its ROLES), in its order."""
    token = _reading.set(True)
    try:
        namespace = runpy.run_path(str(deploy_file), run_name="deploy")
    finally:
        _reading.reset(token)
    listed = namespace.get("ROLES")
    if not listed:
        raise RuntimeError(f"{deploy_file}: lists no ROLES")
    return cards(listed)


def registry_of(roles_: tuple[Role, ...]) -> Registry:
    """Every setting: the engine's own (connection, apt, rollout, pull mode) and the roles'."""
    return Registry(
        (*connection.SETTINGS, *pull_mode.SETTINGS), roles_, connection.ALIASES, (pull_mode.rules,), pull_mode.RENAMED
    )


@functools.lru_cache(maxsize=4)
def registry(deploy_file: Path = DEPLOY) -> Registry:
    return registry_of(roles(deploy_file))


def group_data(group: str) -> dict:
    """What group_data/<group>.py hands pyinfra: the defaults of every setting
    for "all", only those that differ for another group."""
    if group == "all":
        return registry().defaults()
    return registry().group_defaults(group)
