"""Where other roles add to what the docker role builds."""

from robotfleet.role import Hook

DAEMON_OPTIONS = Hook(
    "docker daemon.json",
    "add(data, options) -> options: daemon.json's options with what the role needs merged in "
    "(the gpu role's nvidia runtime); the docker role writes the file and restarts Docker only when it changes.",
)

RESTARTED = Hook(
    "docker restarted",
    "an event the docker role announces (Play.announce) with the operation that restarts Docker for a new "
    "daemon.json; the payload role checks its release after it.",
)
