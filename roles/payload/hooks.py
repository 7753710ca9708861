"""Where other roles add to what the payload role builds, and what they may
read of it (through these functions, never the payload's settings themselves)."""

import roles.payload.services as services
from robotfleet.role import Hook

SERVICES = Hook(
    "payload compose services",
    "add(data, services) -> {service name or '*' for every service: "
    "{environment: {...}, volumes: [...], devices: [...], deploy: {...}}}: what the role gives the compose "
    "services (services: name -> the service as the fleet file declares it): "
    "the X11 socket and cookie, the sensors' devices, the GPUs.",
)
CHECKS = Hook(
    "payload release checks",
    "add(data) -> a command (argv list) run in each container once the release is healthy, or None; "
    "a failing command fails the release, which is rolled back (the gpu role's nvidia-smi -L).",
)


def wants_gpus(data) -> bool:
    """The payload asks for the host's NVIDIA GPUs: the gpu role runs there
    and gives them to its services."""
    return bool(services.value_of(data, "payload_gpu"))


def declared_services(data, refused=frozenset()) -> dict[str, dict]:
    """name -> each compose service as the fleet file declares it (before
    what the roles add); {} where the settings that declare them are refused
    or contradict each other (the payload role's own problems say which)."""
    if {"payload_services", "payload_image"} & set(refused):
        return {}
    if services.value_of(data, "payload_services") and services.value_of(data, "payload_image"):
        return {}
    return services.declared(data)
