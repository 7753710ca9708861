"""Where other roles add to what the docker role builds, and what they may
read of it (through these functions, never the docker role's settings themselves)."""

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


def insecure_registries(data) -> list[str]:
    """The registries Docker on the host reaches over plain HTTP (daemon.json's
    insecure-registries): the payload's push reads them the same way."""
    return list(data.get("docker_insecure_registries") or [])
