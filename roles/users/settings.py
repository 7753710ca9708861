"""The users role's settings."""

from engine import checks as c
from engine import values as v
from engine.role import Setting

SETTINGS = (
    Setting("docker_users", [], c.list_of(v.user_name, unique=True),
            "Existing users added to the docker group (root-equivalent); users are never created."),
)
