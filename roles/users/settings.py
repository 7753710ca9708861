"""The users role's settings."""

from robotfleet import checkers as c
from robotfleet import value_kinds as v
from robotfleet.role import Setting

SETTINGS = (
    Setting("docker_users", [], c.list_of(v.user_name, unique=True),
            "Existing users added to the docker group (root-equivalent); users are never created."),
)
