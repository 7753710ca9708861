"""Where other roles add to what the payload role builds."""

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
