"""The roles: one folder each, owning everything about its concern.

A role's ``__init__.py`` defines ``ROLE = Role(...)`` (robotfleet/role.py): its
settings (default, check, one line of documentation), the host reads it
declares, its steps, the hooks it offers and what it adds to other roles'
hooks.  deploy.py lists the roles in the order they run.  ARCHITECTURE.md
shows how to add a setting and a role.
"""

import importlib


def named(*names: str) -> tuple:
    """The roles called ``names`` (their folders here), in that order: what
    deploy.py's ROLES lists.  A misspelt name is one line naming it."""
    found = []
    for name in names:
        try:
            found.append(importlib.import_module(f"{__name__}.{name}").ROLE)
        except ModuleNotFoundError as error:
            if error.name != f"{__name__}.{name}":
                raise  # a module the role imports is missing: its own error says which
            raise LookupError(f"deploy.py: ROLES names {name!r}, but there is no roles/{name}/") from None
    return tuple(found)
