"""Simulated robots and laptops: `<prefix>-robot1..N`, `<prefix>-laptop1..M`,
and emulated arm64 robots `<prefix>-pi1..K` (group robots).

Each is a systemd container from the host image of its architecture on
`<prefix>-net`, its sshd published on a fixed free 127.0.0.1 port, its nested
Docker state on its own named volumes. `up` is idempotent; `down` removes
everything of one prefix except the shared apt cache volume and the images.
"""

from __future__ import annotations

import logging
import re
import subprocess
import time
import uuid
from pathlib import Path
from typing import TYPE_CHECKING

import paramiko
import yaml

from . import gitserver, hostimage, services, sshd, state
from .engine import REPO_ROOT, LabError, client, get_or_none, pick_free_port, published_ports, put_files, timed_phase
from .machinelock import PORTS_LOCK, machine_lock

if TYPE_CHECKING:
    import docker

GROUP_PREFIXES = {"robots": "robot", "laptops": "laptop"}
# Emulated arm64 robots (a Raspberry Pi or a Jetson beside the amd64 NUCs).
ARM64_ROBOT_PREFIX = "pi"
SSH_PORT_START = 22001
SSH_READY_TIMEOUT_S = 120
# Under qemu-user a host boots and makes its host keys several times slower.
EMULATED_SLOWDOWN = 5
INVENTORY = REPO_ROOT / "inventories" / "lab.yaml"
APT_PROXY_CONF = "/etc/apt/apt.conf.d/01robot-lab-proxy"
PREFIX_PATTERN = re.compile(r"^[a-z0-9][a-z0-9-]{0,30}$")
SENSOR_PATTERN = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")
NESTED_DOCKER_DIRS = {"docker": "/var/lib/docker", "containerd": "/var/lib/containerd"}


def check_prefix(prefix: str) -> str:
    if not PREFIX_PATTERN.match(prefix):
        raise LabError(f"bad lab prefix {prefix!r}: use lowercase letters, digits and '-'")
    return prefix


def plan_hosts(robots: int, laptops: int, arm64_robots: int = 0) -> list[tuple[str, str, str]]:
    """[(host name, group, architecture)] for a lab of that size."""
    counts = {"robots": robots, "laptops": laptops}
    planned = [
        (f"{GROUP_PREFIXES[group]}{i}", group, hostimage.NATIVE_ARCH)
        for group, count in counts.items()
        for i in range(1, count + 1)
    ]
    return planned + [(f"{ARM64_ROBOT_PREFIX}{i}", "robots", "arm64") for i in range(1, arm64_robots + 1)]


def sensors_from_inventory(path: Path = INVENTORY) -> dict[str, list[str]]:
    """Sensor names per robot declared in inventories/lab.yaml (if it exists)."""
    if not path.exists():
        return {}
    fleet = yaml.safe_load(path.read_text()) or {}
    declared = (fleet.get("robots") or {}).get("hosts") or {}
    return {host: [s["name"] for s in (data or {}).get("udev_sensors") or []] for host, data in declared.items()}


def known_hosts_line(port: int, public_key: str) -> str:
    """A known_hosts line for a key ("type base64 [comment]") on 127.0.0.1:port."""
    key_type, key_b64 = public_key.split()[:2]
    host = "127.0.0.1" if port == 22 else f"[127.0.0.1]:{port}"
    return f"{host} {key_type} {key_b64}"


def apt_proxy_conf(services_host: str) -> str:
    return (
        f'Acquire::http::Proxy "http://{services_host}:{services.APT_CACHE_PORT}";\n'
        f'Acquire::http::Proxy::{services_host} "DIRECT";\n'
    )


INOTIFY_INSTANCES = Path("/proc/sys/fs/inotify/max_user_instances")
INOTIFY_WANTED = 1024


def _raise_inotify_instances() -> None:
    """Every host runs systemd (and later dockerd), each taking inotify
    instances from one per-user pool shared by all containers: at the kernel
    default of 128 a few labs side by side make a host exit at boot (status
    255, no log).  Raise it where we may (root); otherwise say what to do."""
    try:
        current = int(INOTIFY_INSTANCES.read_text())
        if current >= INOTIFY_WANTED:
            return
        INOTIFY_INSTANCES.write_text(f"{INOTIFY_WANTED}\n")
        logging.getLogger(__name__).info(
            "lab: raised fs.inotify.max_user_instances from %s to %s", current, INOTIFY_WANTED
        )
    except (OSError, ValueError):
        print(
            f"lab: fs.inotify.max_user_instances is low; if hosts exit at boot, run "
            f"`sysctl -w fs.inotify.max_user_instances={INOTIFY_WANTED}` as root",
            flush=True,
        )


def up(
    prefix: str = "lab",
    robots: int = 3,
    laptops: int = 1,
    sensors: dict[str, list[str]] | list[str] | None = None,
    arm64_robots: int = 0,
    git_server: bool = False,
) -> dict:
    """Start (or reuse) a lab and write its state.json; returns the state.

    `sensors`: names per robot, or one list for every robot; default: what
    inventories/lab.yaml declares.  `arm64_robots`: emulated arm64 robots
    pi1..N (qemu-user, tests/lab/emulation.py).  `git_server`: also the
    git server pull mode uses (tests/lab/gitserver.py); a lab that has one
    keeps it.
    """
    check_prefix(prefix)
    wanted = plan_hosts(robots, laptops, arm64_robots)
    sensors_by_host = _sensors_by_host(sensors, [name for name, group, _ in wanted if group == "robots"])
    _raise_inotify_instances()
    dc = client()
    if any(arch != hostimage.NATIVE_ARCH for _, _, arch in wanted):
        from .emulation import ensure_arm64_emulation

        ensure_arm64_emulation()  # registered on every up: a reboot forgets it
    with timed_phase("build images (cached by recipe)"):
        host_image = hostimage.ensure_host_image(dc)
        host_images = {
            arch: hostimage.ensure_host_image(dc, arch)
            for arch in sorted({arch for _, _, arch in wanted} - {hostimage.NATIVE_ARCH})
        }
        host_images[hostimage.NATIVE_ARCH] = host_image
        services_image = services.ensure_services_image(dc, host_image)
        mirror_dir = services.mirror_dir()
    network = _ensure_network(dc, prefix)
    key_path = _ensure_ssh_key(prefix)
    with timed_phase("start services"):
        registry_port = services.ensure_services(dc, prefix, network, services_image, mirror_dir)
    with timed_phase("payload images in the lab registry"), machine_lock("payload images"):
        from . import payload_images

        try:
            payload_images.build_payload_images(dc, f"127.0.0.1:{registry_port}")
        except payload_images.PayloadImageError as error:
            raise LabError(str(error)) from None
    _remove_hosts_not_in(dc, prefix, {name for name, _, _ in wanted})
    services_host = services.container_name(prefix)
    with timed_phase(f"start hosts ({len(wanted)})"):
        started = [
            _ensure_host(
                dc,
                prefix,
                name,
                group,
                host_images[arch],
                key_path,
                apt_proxy_conf(services_host),
                sensors_by_host.get(name, []),
            )
            for name, group, arch in wanted
        ]
        for (_, _, arch), (container, _) in zip(wanted, started):
            if arch != hostimage.NATIVE_ARCH:
                from . import native_runc

                native_runc.install(container)  # lab only: qemu-user's runc cannot start containers
    known_hosts = state.lab_dir(prefix) / "known_hosts"
    with timed_phase("wait for ssh"):
        lines = []
        for (_, _, arch), (container, port) in zip(wanted, started):
            lines += [known_hosts_line(port, k) for k in sshd.wait_for_host_keys(container, ready_timeout(arch))]
        known_hosts.write_text("\n".join(lines) + "\n")
        for (_, _, arch), (container, port) in zip(wanted, started):
            _wait_for_ssh_login(container.name, port, key_path, known_hosts, ready_timeout(arch))
    lab = {
        "prefix": prefix,
        "ssh_key": str(key_path),
        "known_hosts": str(known_hosts),
        "ssh_user": hostimage.OPS_USER,
        "hosts": [
            {"name": name, "group": group, "arch": arch, "container": c.name, "port": port}
            for (name, group, arch), (c, port) in zip(wanted, started)
        ],
        "services_host": services_host,
        "apt_proxy": f"http://{services_host}:{services.APT_CACHE_PORT}",
        "registry": f"{services_host}:{services.REGISTRY_PORT}",
        "registry_local": f"127.0.0.1:{registry_port}",
        "mirror_url": f"http://{services_host}:{services.STATIC_PORT}/linux",
        "mirror_dir": str(mirror_dir),
    }
    if git_server or _has_git_server(dc, prefix):
        lab["git"] = gitserver.ensure(dc, prefix, key_path)
    path = state.save(lab)
    print(f"lab: '{prefix}' is up: {len(started)} hosts; state in {path}")
    return lab


def add_git_server(prefix: str) -> dict:
    """Start the git server beside a running lab (idempotent); returns the
    lab's state, which now names it under "git"."""
    lab = state.load(prefix)
    lab["git"] = gitserver.ensure(client(), prefix, Path(lab["ssh_key"]))
    state.save(lab)
    return lab


def git_server_alone(prefix: str) -> tuple[dict, Path]:
    """Start (or reuse) only the git server of lab ``prefix``: its network,
    its key and gitolite, no services and no hosts (what the git server's
    benchmarks need).  (state.json's "git", the lab key); `down` removes it."""
    check_prefix(prefix)
    dc = client()
    _ensure_network(dc, prefix)
    key_path = _ensure_ssh_key(prefix)
    return gitserver.ensure(dc, prefix, key_path), key_path


def _has_git_server(dc, prefix: str) -> bool:
    return get_or_none(dc.containers, gitserver.container_name(prefix)) is not None


def down(prefix: str = "lab") -> None:
    check_prefix(prefix)
    dc = client()
    label = {"label": f"robot-lab.prefix={prefix}"}
    for container in dc.containers.list(all=True, filters=label):
        container.remove(force=True)
    for network in dc.networks.list(filters=label):
        network.remove()
    for volume in dc.volumes.list(filters=label):
        volume.remove(force=True)
    state.forget(prefix)
    for name in ("known_hosts", "git_known_hosts"):
        (state.lab_dir(prefix) / name).unlink(missing_ok=True)
    print(f"lab: '{prefix}' is down")


def reset(
    prefix: str = "lab",
    robots: int | None = None,
    laptops: int | None = None,
    sensors: dict[str, list[str]] | list[str] | None = None,
    arm64_robots: int | None = None,
    git_server: bool | None = None,
) -> dict:
    """Down then up with fresh hosts; sizes (and the git server) default to the previous lab's."""
    previous = _previous_sizes(prefix)
    down(prefix)
    return up(
        prefix,
        robots if robots is not None else previous.get("robots", 3),
        laptops if laptops is not None else previous.get("laptops", 1),
        sensors,
        arm64_robots if arm64_robots is not None else previous.get("arm64_robots", 0),
        git_server if git_server is not None else bool(previous.get("git_server")),
    )


def status(prefix: str = "lab") -> list[str]:
    """One line per container of the lab."""
    check_prefix(prefix)
    dc = client()
    containers = dc.containers.list(all=True, filters={"label": f"robot-lab.prefix={prefix}"})
    if not containers:
        return [f"lab '{prefix}': no containers (down)"]
    known_hosts = state.lab_dir(prefix) / "known_hosts"
    key_path = state.lab_dir(prefix) / "id_ed25519"
    lines = []
    for c in sorted(containers, key=lambda c: c.name):
        if c.labels.get("robot-lab.role") == "services":
            port = c.labels.get("robot-lab.registry-port")
            lines.append(f"{c.name:<24} {c.status:<9} registry 127.0.0.1:{port}")
            continue
        if c.labels.get("robot-lab.role") == "git":
            lines.append(f"{c.name:<24} {c.status:<9} git (gitolite3) ssh 127.0.0.1:{c.labels['robot-lab.ssh-port']}")
            continue
        port = int(c.labels["robot-lab.ssh-port"])
        reachable = c.status == "running" and _ssh_login_error(port, key_path, known_hosts) is None
        lines.append(f"{c.name:<24} {c.status:<9} ssh 127.0.0.1:{port:<6} reachable {'yes' if reachable else 'no'}")
    return lines


def _previous_sizes(prefix: str) -> dict[str, int]:
    try:
        previous = state.load(prefix)
    except LabError:
        return {}
    hosts = previous["hosts"]
    native = [h for h in hosts if h.get("arch", hostimage.NATIVE_ARCH) == hostimage.NATIVE_ARCH]
    sizes = {group: sum(h["group"] == group for h in native) for group in GROUP_PREFIXES}
    sizes["arm64_robots"] = len(hosts) - len(native)
    sizes["git_server"] = int("git" in previous)
    return sizes


def ready_timeout(arch: str) -> int:
    """Seconds a host of ``arch`` may take to boot and answer ssh."""
    return SSH_READY_TIMEOUT_S * (1 if arch == hostimage.NATIVE_ARCH else EMULATED_SLOWDOWN)


def _sensors_by_host(sensors, robots: list[str]) -> dict[str, list[str]]:
    if sensors is None:
        by_host = sensors_from_inventory()
    elif isinstance(sensors, dict):
        by_host = sensors
    else:
        by_host = {name: list(sensors) for name in robots}
    for names in by_host.values():
        for name in names:
            if not SENSOR_PATTERN.match(name):
                raise LabError(f"bad sensor name {name!r}")
    return by_host


def _ensure_network(dc: docker.DockerClient, prefix: str) -> str:
    name = f"{prefix}-net"
    if not any(n.name == name for n in dc.networks.list(names=[name])):
        dc.networks.create(name, driver="bridge", labels={"robot-lab.prefix": prefix})
    return name


def _ensure_ssh_key(prefix: str) -> Path:
    key = state.lab_dir(prefix) / "id_ed25519"
    key.parent.mkdir(parents=True, exist_ok=True)
    if not key.exists():
        subprocess.run(
            ["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-C", f"robot-lab-{prefix}", "-f", str(key)], check=True
        )
    key.chmod(0o600)
    return key.resolve()


def _remove_hosts_not_in(dc: docker.DockerClient, prefix: str, names: set[str]) -> None:
    label = f"robot-lab.prefix={prefix}"
    for c in dc.containers.list(all=True, filters={"label": [label, "robot-lab.role=host"]}):
        if c.labels.get("robot-lab.host") not in names:
            c.remove(force=True)
    for volume in dc.volumes.list(filters={"label": [label, "robot-lab.host"]}):
        if (volume.attrs.get("Labels") or {}).get("robot-lab.host") not in names:
            volume.remove(force=True)


def _host_volume_names(prefix: str, host: str) -> dict[str, str]:
    return {f"{prefix}-{host}-{kind}": path for kind, path in NESTED_DOCKER_DIRS.items()}


def _ensure_host(dc, prefix, host, group, image, key_path: Path, apt_conf: str, sensors: list[str]):
    """(container, ssh port) of a started host, created if needed."""
    name = f"{prefix}-{host}"
    container = get_or_none(dc.containers, name)
    if container is not None and (
        container.labels.get("robot-lab.image") != image or container.labels.get("robot-lab.group") != group
    ):
        container.remove(force=True)
        container = None
    was_running = container is not None and container.status == "running"
    if container is None:
        container = _create_host(dc, prefix, host, group, image)
    old_sensors = _read_file(container, hostimage.SENSORS_LIST) if was_running else None
    new_sensors = "".join(f"{s}\n" for s in sensors)
    put_files(container, {APT_PROXY_CONF: apt_conf, hostimage.SENSORS_LIST: new_sensors})
    put_files(
        container,
        {f"/home/{hostimage.OPS_USER}/.ssh/authorized_keys": key_path.with_suffix(".pub").read_text()},
        mode=0o600,
        owner=(hostimage.USER_UIDS[hostimage.OPS_USER],) * 2,
    )
    if not was_running:
        container.start()
    elif old_sensors != new_sensors:
        container.exec_run(["systemctl", "restart", "robot-lab-sensors.service"])
    return container, int(container.labels["robot-lab.ssh-port"])


def _create_host(dc, prefix, host, group, image):
    volumes = {}
    for volume, path in _host_volume_names(prefix, host).items():
        if get_or_none(dc.volumes, volume) is None:
            dc.volumes.create(volume, labels={"robot-lab.prefix": prefix, "robot-lab.host": host})
        volumes[volume] = path
    with machine_lock(PORTS_LOCK):  # the port is taken once the container exists
        port = pick_free_port(SSH_PORT_START, published_ports(dc))
        container = hostimage.create_systemd_container(
            dc,
            image,
            f"{prefix}-{host}",
            hostname=host,
            network=f"{prefix}-net",
            labels={
                "robot-lab.prefix": prefix,
                "robot-lab.role": "host",
                "robot-lab.host": host,
                "robot-lab.group": group,
                "robot-lab.image": image,
                "robot-lab.ssh-port": str(port),
            },
            ports={22: port},
            volumes=volumes,
        )
    put_files(container, {"/etc/machine-id": uuid.uuid4().hex + "\n"})
    return container


def _read_file(container, path: str) -> str | None:
    code, out = container.exec_run(["cat", path])
    return out.decode() if code == 0 else None


def _ssh_login_error(port: int, key_path: Path, known_hosts: Path) -> str | None:
    """None if ops can log in with the lab key and sudo, checking host keys strictly."""
    # Unanswered retries would otherwise print paramiko tracebacks.
    logging.getLogger("paramiko").addHandler(logging.NullHandler())
    ssh = paramiko.SSHClient()
    try:
        ssh.load_host_keys(str(known_hosts))
        ssh.set_missing_host_key_policy(paramiko.RejectPolicy())
        ssh.connect(
            "127.0.0.1",
            port=port,
            username=hostimage.OPS_USER,
            key_filename=str(key_path),
            timeout=5,
            banner_timeout=5,
            auth_timeout=5,
            look_for_keys=False,
            allow_agent=False,
        )
        _, stdout, _ = ssh.exec_command("sudo -n true", timeout=10)
        code = stdout.channel.recv_exit_status()
        return None if code == 0 else f"`sudo -n true` exited {code}"
    except paramiko.BadHostKeyException as e:
        return f"host key mismatch: {e}"
    except (paramiko.SSHException, OSError) as e:
        return f"{type(e).__name__}: {e}"
    finally:
        ssh.close()


def _wait_for_ssh_login(
    name: str, port: int, key_path: Path, known_hosts: Path, timeout: int = SSH_READY_TIMEOUT_S
) -> None:
    deadline = time.monotonic() + timeout
    while True:
        error = _ssh_login_error(port, key_path, known_hosts)
        if error is None:
            return
        if error.startswith("host key mismatch") or time.monotonic() > deadline:
            raise LabError(f"{name}: ssh ops@127.0.0.1:{port} fails: {error}")
        time.sleep(1)
