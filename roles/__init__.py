"""The roles: one folder each, owning everything about its concern.

A role's ``__init__.py`` defines ``ROLE = Role(...)`` (engine/role.py): its
settings (default, check, one line of documentation), the host reads it
declares, its steps, the hooks it offers and what it adds to other roles'
hooks.  deploy.py lists the roles in the order they run.  ARCHITECTURE.md
shows how to add a setting and a role.
"""
