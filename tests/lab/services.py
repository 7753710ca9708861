"""The per-lab "services" container `<prefix>-services` on `<prefix>-net`.

It runs (systemd as PID 1, like the hosts):
  3142  apt-cacher-ng; its cache is the named volume robot-lab-aptcache,
        shared by every lab on this machine so repeated installs are fast
  5000  Debian's docker-registry (distribution v2); also published on
        127.0.0.1:<port> so the outer engine can push to it
  8080  a static HTTP server over the Docker CE mirror directory (read-only)
"""

from __future__ import annotations

import importlib.util
import time
import urllib.request
import uuid
from pathlib import Path
from typing import TYPE_CHECKING

from . import apt_install, hostimage
from .engine import LAB_DIR, LabError, get_or_none, pick_free_port, published_ports, put_files, timed_phase
from .machinelock import PORTS_LOCK, machine_lock

if TYPE_CHECKING:
    import docker

SERVICES_REPO = "robot-lab-services"
APT_CACHE_VOLUME = "robot-lab-aptcache"
APT_CACHE_PORT, REGISTRY_PORT, STATIC_PORT = 3142, 5000, 8080
DEFAULT_MIRROR_DIR = LAB_DIR / "cache" / "docker-mirror"
REGISTRY_LOCAL_PORT_START = 25000
# The mirror directory's parent is bound, not the directory itself, so a
# mirror rebuilt by replacing its directory is still what gets served.
MIRROR_PARENT_MOUNT = "/srv/robot-lab-mirror-parent"
STATIC_ENV = "/etc/robot-lab/static.env"
READY_TIMEOUT_S = 90

PACKAGES = ("apt-cacher-ng", "docker-registry")

_STATIC_UNIT = f"""[Unit]
Description=Robot lab: static files (Docker CE mirror) on :{STATIC_PORT}
After=network.target

[Service]
EnvironmentFile={STATIC_ENV}
ExecStart=/usr/bin/python3 -m http.server {STATIC_PORT} --directory ${{STATIC_DIR}}
Restart=always
RestartSec=1

[Install]
WantedBy=multi-user.target
"""

# The shared cache volume may come from an older image whose apt-cacher-ng
# user had another uid.
_ACNG_DROPIN = """[Service]
ExecStartPre=+/bin/sh -c '[ "$(stat -c %U /var/cache/apt-cacher-ng)" = apt-cacher-ng ] || \
chown -R apt-cacher-ng:apt-cacher-ng /var/cache/apt-cacher-ng'
"""

_REGISTRY_CONFIG = f"""version: 0.1
storage:
  filesystem:
    rootdirectory: /var/lib/docker-registry
  delete:
    enabled: true
http:
  addr: :{REGISTRY_PORT}
"""

# Debian's default registry config asks for htpasswd auth; the lab's is open.
_REGISTRY_DROPIN = """[Service]
ExecStart=
ExecStart=/usr/bin/docker-registry serve /etc/robot-lab/registry.yml
"""

SERVICES_FILES = {
    "etc/robot-lab/registry.yml": _REGISTRY_CONFIG,
    "etc/systemd/system/docker-registry.service.d/robot-lab.conf": _REGISTRY_DROPIN,
    "etc/systemd/system/robot-lab-static.service": _STATIC_UNIT,
    "etc/systemd/system/apt-cacher-ng.service.d/robot-lab.conf": _ACNG_DROPIN,
}

INSTALL_SCRIPT = f"""set -eu
{apt_install.script(PACKAGES)}systemctl enable apt-cacher-ng.service docker-registry.service robot-lab-static.service
systemctl disable ssh.service
apt-get clean
rm -rf /var/lib/apt/lists/*
"""

_DOCKERFILE = """FROM {host}
COPY rootfs/ /
COPY install.sh /tmp/install.sh
RUN sh /tmp/install.sh && rm /tmp/install.sh
"""


def container_name(prefix: str) -> str:
    return f"{prefix}-services"


def services_recipe() -> dict:
    return {
        "host": hostimage.host_recipe(),
        "packages": list(PACKAGES),
        "files": SERVICES_FILES,
        "script": INSTALL_SCRIPT,
        "dockerfile": _DOCKERFILE,
    }


def services_tag() -> str:
    return f"{SERVICES_REPO}:{hostimage.recipe_hash(services_recipe())}"


def ensure_services_image(dc: docker.DockerClient, host_tag: str) -> str:
    tag = services_tag()
    if hostimage.image_exists(dc, tag):
        return tag
    with machine_lock(f"image {tag}"), timed_phase(f"build services image {tag}"):
        if hostimage.image_exists(dc, tag):  # another lab built it meanwhile
            return tag
        files = {f"rootfs/{path}": text for path, text in SERVICES_FILES.items()}
        files["install.sh"] = INSTALL_SCRIPT
        hostimage.build_image(dc, tag, _DOCKERFILE.format(host=host_tag), files)
    return tag


def mirror_dir() -> Path:
    """The Docker CE mirror directory to serve on :8080 (built if we can).

    Its `linux/` subdirectory is what `mirror_url` points at.
    """
    if importlib.util.find_spec(f"{__package__}.mirror") is None:
        DEFAULT_MIRROR_DIR.mkdir(parents=True, exist_ok=True)
        return DEFAULT_MIRROR_DIR
    from . import mirror

    try:
        built = mirror.build_mirror(DEFAULT_MIRROR_DIR)
    except getattr(mirror, "MirrorError", LabError) as e:
        raise LabError(f"building the Docker CE mirror failed: {e}") from None
    root = built.get("root") if isinstance(built, dict) else built
    root = Path(root or DEFAULT_MIRROR_DIR).resolve()
    from . import nvidia_mirror  # the NVIDIA-style repository, served beside Docker's

    nvidia_mirror.build_into(root)
    return root


def ensure_services(dc: docker.DockerClient, prefix: str, network: str, image: str, mirror: Path) -> int:
    """Start (or reuse) the services container; returns its registry's local port."""
    name = container_name(prefix)
    wanted = {
        "robot-lab.prefix": prefix,
        "robot-lab.role": "services",
        "robot-lab.image": image,
        "robot-lab.mirror": str(mirror),
    }
    container = get_or_none(dc.containers, name)
    if container is not None and any(container.labels.get(k) != v for k, v in wanted.items()):
        container.remove(force=True)
        container = None
    if container is None:
        container = _create(dc, name, network, image, mirror, wanted)
    if container.status != "running":
        container.start()
    port = int(container.labels["robot-lab.registry-port"])
    _wait_ready(container, port)
    return port


def _create(dc, name, network, image, mirror: Path, labels: dict):
    with machine_lock(PORTS_LOCK):  # the port is taken once the container exists
        port = pick_free_port(REGISTRY_LOCAL_PORT_START, published_ports(dc))
        container = hostimage.create_systemd_container(
            dc,
            image,
            name,
            hostname="services",
            network=network,
            labels={**labels, "robot-lab.registry-port": str(port)},
            ports={REGISTRY_PORT: port},
            volumes={APT_CACHE_VOLUME: "/var/cache/apt-cacher-ng", str(mirror.parent): f"{MIRROR_PARENT_MOUNT}:ro"},
        )
    put_files(
        container,
        {
            STATIC_ENV: f"STATIC_DIR={MIRROR_PARENT_MOUNT}/{mirror.name}\n",
            "/etc/machine-id": uuid.uuid4().hex + "\n",
        },
    )
    return container


_PROBES = {
    "apt-cacher-ng": f"curl -s -o /dev/null -w '%{{http_code}}' http://127.0.0.1:{APT_CACHE_PORT}/acng-report.html",
    "registry": f"curl -s -o /dev/null -w '%{{http_code}}' http://127.0.0.1:{REGISTRY_PORT}/v2/",
    "static files": f"curl -s -o /dev/null -w '%{{http_code}}' http://127.0.0.1:{STATIC_PORT}/",
}


def _local_registry_answers(port: int) -> bool:
    direct = urllib.request.build_opener(urllib.request.ProxyHandler({}))
    try:
        with direct.open(f"http://127.0.0.1:{port}/v2/", timeout=3) as r:
            return r.status == 200
    except OSError:
        return False


def _wait_ready(container, registry_local_port: int) -> None:
    waiting = dict(_PROBES)
    waiting["registry on 127.0.0.1"] = None
    deadline = time.monotonic() + READY_TIMEOUT_S
    while waiting and time.monotonic() < deadline:
        container.reload()
        if container.status not in ("running", "created"):
            raise LabError(f"{container.name} stopped ({container.status}); see `docker logs {container.name}`")
        for what, probe in list(waiting.items()):
            if probe is None:
                ok = _local_registry_answers(registry_local_port)
            else:
                code, out = container.exec_run(["sh", "-c", probe])
                ok = code == 0 and out.decode().strip() == "200"
            if ok:
                del waiting[what]
        if waiting:
            time.sleep(1)
    if waiting:
        raise LabError(
            f"{container.name}: {', '.join(waiting)} did not answer within "
            f"{READY_TIMEOUT_S}s (docker exec {container.name} systemctl --failed)"
        )
