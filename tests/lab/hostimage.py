"""The Debian 13 image every simulated robot and laptop runs (systemd as PID 1).

Built in two cached layers, each tagged by a hash of its full recipe so a
machine builds it once and rebuilds only when the recipe changes:
  robot-lab-base:<sha12>  mmdebstrap rootfs (suite, mirror, package list, architecture)
  robot-lab-host:<sha12>  + lab customisation (users, units, no host keys)
Docker itself is deliberately NOT preinstalled: the provisioner installs it.

The arm64 image (the emulated robot) is the same recipe for another
architecture: `mmdebstrap --arch=arm64` downloads the packages here and
runs the arm64 dpkg and maintainer scripts in a chroot under qemu-user
(binfmt_misc, tests/lab/emulation.py), and the host layer's build
runs its arm64 shell the same way.  No emulator is copied into the image.
"""

from __future__ import annotations

import hashlib
import io
import json
import subprocess
import tarfile
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

from .debian_archive import ArchiveError, debian_archive_url
from .engine import LAB_DIR, LabError, get_or_none, timed_phase
from .machinelock import machine_lock

if TYPE_CHECKING:
    import docker

SUITE = "trixie"
VARIANT = "minbase"
INCLUDE_PACKAGES = (
    "systemd",
    "systemd-sysv",
    "dbus",
    "udev",
    "openssh-server",
    "sudo",
    "python3",
    "ca-certificates",
    "curl",
    "gnupg",
    "iproute2",
    "procps",
    "less",
)
ARCHES = ("amd64", "arm64")
NATIVE_ARCH = "amd64"
BASE_REPO = "robot-lab-base"
HOST_REPO = "robot-lab-host"
BUILD_DIR = LAB_DIR / "cache" / "build"

OPS_USER = "ops"
USER_UIDS = {"ops": 1000, "ros": 1001, "alice": 1002}

SENSORS_LIST = "/etc/robot-lab/sensors"

_SENSORS_SCRIPT = """#!/bin/sh
# Fake udev-named sensors: /dev/robot/NAME -> ../lab-sensors/NAME, a char
# device 1:3 (what /dev/null is) so compose `devices:` entries can map it.
set -eu
mkdir -p /dev/lab-sensors /dev/robot
rm -f /dev/lab-sensors/*
for link in /dev/robot/*; do
    if [ -L "$link" ] && [ ! -e "$link" ]; then rm -f "$link"; fi
done
[ -f %(list)s ] || exit 0
while read -r name; do
    case "$name" in ''|'#'*) continue ;; esac
    mknod -m 0660 "/dev/lab-sensors/$name" c 1 3
    chgrp dialout "/dev/lab-sensors/$name"
    ln -sfn "../lab-sensors/$name" "/dev/robot/$name"
done < %(list)s
""" % {"list": SENSORS_LIST}

_SENSORS_UNIT = (
    """[Unit]
Description=Robot lab: fake sensor device nodes from %s
DefaultDependencies=no
After=systemd-tmpfiles-setup-dev.service
Before=sysinit.target docker.service

[Service]
Type=oneshot
RemainAfterExit=yes
ExecStart=/usr/local/sbin/robot-lab-sensors

[Install]
WantedBy=sysinit.target
"""
    % SENSORS_LIST
)

# Debian only generates host keys on "first boot"; our containers are never
# that (machine-id is written before start), so drop the condition: every
# host then makes its own keys when it first starts.
_SSHD_KEYGEN_DROPIN = """[Unit]
ConditionFirstBoot=
"""

HOST_FILES = {
    "usr/local/sbin/robot-lab-sensors": _SENSORS_SCRIPT,
    "etc/systemd/system/robot-lab-sensors.service": _SENSORS_UNIT,
    "etc/systemd/system/sshd-keygen.service.d/robot-lab.conf": _SSHD_KEYGEN_DROPIN,
}

# Only in the emulated (arm64) image: what qemu-user cannot do, turned off.
# qemu-user refuses clone() with CLONE_NEWNS (a fork into a new mount
# namespace), which systemd needs for a unit's credentials and filesystem
# sandboxing: journald, logind, tmpfiles, sysusers and chrony would exit
# 243/CREDENTIALS or 226/NAMESPACE.  Every service runs unsandboxed instead.
_QEMU_USER_SERVICES_DROPIN = """[Service]
ImportCredential=
LoadCredential=
PrivateTmp=no
PrivateDevices=no
ProtectSystem=no
ProtectHome=no
ProtectKernelTunables=no
ProtectKernelModules=no
ProtectKernelLogs=no
ProtectControlGroups=no
ProtectProc=default
ProcSubset=all
PrivateMounts=no
ReadWritePaths=
ReadOnlyPaths=
InaccessiblePaths=
"""

# qemu-user has no netfilter sockets (iptables: "Failed to initialize nft:
# Protocol not supported"), so dockerd starts only without iptables; the
# fleet file says the same for the emulated robots (inventories/lab.yaml).
_QEMU_USER_DAEMON_JSON = '{"iptables": false}\n'

EMULATED_HOST_FILES = {
    "etc/systemd/system/service.d/10-robot-lab-qemu-user.conf": _QEMU_USER_SERVICES_DROPIN,
    "etc/docker/daemon.json": _QEMU_USER_DAEMON_JSON,
}


# The per-user systemd manager (user@UID.service, which logind starts for
# every SSH login) hangs under qemu-user starting its socket units (their
# `systemctl --user` calls never return): each login waited for its 90 s
# start timeout and pam_systemd's D-Bus timeout, over two minutes.  Nothing
# on a robot needs it.
EMULATED_SCRIPT = """systemctl mask user@.service
"""


def host_files(arch: str = "amd64") -> dict[str, str]:
    return {**HOST_FILES, **(EMULATED_HOST_FILES if arch != "amd64" else {})}


def customise_script(arch: str = "amd64") -> str:
    return CUSTOMISE_SCRIPT + (EMULATED_SCRIPT if arch != "amd64" else "")


_USERADDS = "\n".join(
    f"useradd --create-home --shell /bin/bash --uid {uid} {name}\n"
    f"usermod --password '*' {name}"  # no password, but not "locked" for sshd
    for name, uid in USER_UIDS.items()
)

CUSTOMISE_SCRIPT = f"""set -eu
rm -f /etc/ssh/ssh_host_*
: > /etc/machine-id
{_USERADDS}
install -d -m 0700 -o {OPS_USER} -g {OPS_USER} /home/{OPS_USER}/.ssh
echo '{OPS_USER} ALL=(ALL) NOPASSWD:ALL' > /etc/sudoers.d/{OPS_USER}
chmod 0440 /etc/sudoers.d/{OPS_USER}
chmod 0755 /usr/local/sbin/robot-lab-sensors
install -d /etc/robot-lab
systemctl enable robot-lab-sensors.service
# A timer-started unattended apt run would hold the dpkg lock mid-deploy.
systemctl mask apt-daily.timer apt-daily-upgrade.timer
# Like a cloud image: no package lists, so nothing stale; run apt-get update.
apt-get clean
rm -rf /var/lib/apt/lists/*
"""

_HOST_DOCKERFILE = """FROM {base}
COPY rootfs/ /
COPY customise.sh /tmp/customise.sh
RUN sh /tmp/customise.sh && rm /tmp/customise.sh
STOPSIGNAL SIGRTMIN+3
CMD ["/lib/systemd/systemd"]
"""


def recipe_hash(recipe: object) -> str:
    """A short stable hash of a JSON-able recipe."""
    blob = json.dumps(recipe, sort_keys=True, separators=(",", ":")).encode()
    return hashlib.sha256(blob).hexdigest()[:12]


def debian_url() -> str:
    """This machine's Debian archive (its apt sources; ROBOT_LAB_DEBIAN_URL overrides)."""
    try:
        return debian_archive_url()
    except ArchiveError as error:
        raise LabError(str(error)) from None


def check_arch(arch: str) -> str:
    if arch not in ARCHES:
        raise LabError(f"no lab host image for architecture {arch!r} (have: {', '.join(ARCHES)})")
    return arch


def base_recipe(arch: str = NATIVE_ARCH) -> dict:
    recipe = {
        "builder": "mmdebstrap",
        "suite": SUITE,
        "mirror": debian_url(),
        "variant": VARIANT,
        "include": list(INCLUDE_PACKAGES),
    }
    if check_arch(arch) != NATIVE_ARCH:
        # Only foreign images name their architecture: the amd64 recipe, and
        # so every machine's cached amd64 image, stays what it was.
        recipe["arch"] = arch
    return recipe


def host_recipe(arch: str = NATIVE_ARCH) -> dict:
    return {
        "base": base_recipe(arch),
        "files": host_files(arch),
        "script": customise_script(arch),
        "dockerfile": _HOST_DOCKERFILE,
    }


def base_tag(arch: str = NATIVE_ARCH) -> str:
    return f"{BASE_REPO}:{recipe_hash(base_recipe(arch))}"


def host_tag(arch: str = NATIVE_ARCH) -> str:
    return f"{HOST_REPO}:{recipe_hash(host_recipe(arch))}"


def image_exists(dc: docker.DockerClient, tag: str) -> bool:
    return get_or_none(dc.images, tag) is not None


def ensure_host_image(dc: docker.DockerClient, arch: str = NATIVE_ARCH) -> str:
    """Tag of the host image for ``arch``, building whatever layer is missing."""
    tag = host_tag(arch)
    if image_exists(dc, tag):
        return tag
    with machine_lock(f"image {tag}"):  # another lab may be building it: wait, then use its build
        if image_exists(dc, tag):
            return tag
        base = base_tag(arch)
        if arch != NATIVE_ARCH:
            from .emulation import ensure_arm64_emulation

            ensure_arm64_emulation()
        if not image_exists(dc, base):
            with timed_phase(f"build base image {base} (mmdebstrap {SUITE} {arch})"):
                _mmdebstrap_and_import(dc, base, arch)
        with timed_phase(f"build host image {tag} ({arch})"):
            files = {f"rootfs/{path}": text for path, text in host_files(arch).items()}
            files["customise.sh"] = customise_script(arch)
            build_image(dc, tag, _HOST_DOCKERFILE.format(base=base), files)
    return tag


def mmdebstrap_command(out: str, arch: str = NATIVE_ARCH) -> list[str]:
    """The command that writes the rootfs as a tar to ``out`` ("-": stdout).
    A foreign architecture's maintainer scripts run in the chroot under
    emulation; apt and the downloads run here.  mmdebstrap, not debootstrap:
    one apt run instead of debootstrap's second stage (which re-unpacks every
    package and greps the suite's whole package list, all under emulation),
    half the arm64 build's CPU (446 against 720-900 core-seconds) and 27
    against 64 for amd64 (2026-12-03)."""
    command = ["mmdebstrap", "--mode=root", f"--variant={VARIANT}", "--include=" + ",".join(INCLUDE_PACKAGES)]
    if arch != NATIVE_ARCH:
        command.append(f"--arch={arch}")
    return command + [SUITE, out, debian_url()]


def _mmdebstrap_and_import(dc: docker.DockerClient, tag: str, arch: str = NATIVE_ARCH) -> None:
    BUILD_DIR.mkdir(parents=True, exist_ok=True)
    log_path = BUILD_DIR / f"mmdebstrap-{arch}.log"
    repo, _, version = tag.partition(":")
    with tempfile.TemporaryDirectory(dir=BUILD_DIR) as tmp, open(log_path, "wb") as log:
        layer = Path(tmp, "layer.tar")
        out = "-" if arch == NATIVE_ARCH else str(layer)
        try:
            build = subprocess.Popen(mmdebstrap_command(out, arch), stdout=subprocess.PIPE, stderr=log)
        except FileNotFoundError:
            raise LabError(
                "cannot build the host image: mmdebstrap is not installed (apt-get install mmdebstrap)"
            ) from None
        try:
            if arch == NATIVE_ARCH:  # the tar on stdout, straight into the engine
                dc.api.import_image_from_stream(build.stdout, repository=repo, tag=version)
        finally:
            build.stdout.close()
            if build.wait() != 0:
                raise LabError(f"mmdebstrap {SUITE} ({arch}) failed (exit {build.returncode}); see {log_path}")
        if arch != NATIVE_ARCH:
            load_layer(dc, layer, tag, arch, tmp)


def rootfs_image_archive(layer: Path, tag: str, arch: str, out: Path) -> None:
    """A `docker load` archive of one layer (an uncompressed rootfs tar)
    whose config says linux/``arch``."""
    digest = hashlib.sha256()
    with open(layer, "rb") as f:
        while chunk := f.read(1 << 20):
            digest.update(chunk)
    diff_id = f"sha256:{digest.hexdigest()}"
    config = json.dumps(
        {
            "architecture": arch,
            "os": "linux",
            **({"variant": "v8"} if arch == "arm64" else {}),
            "config": {"Env": ["PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin"]},
            "rootfs": {"type": "layers", "diff_ids": [diff_id]},
            "history": [{"created_by": f"mmdebstrap {SUITE} ({arch}, robot lab)"}],
        },
        sort_keys=True,
    ).encode()
    config_name = hashlib.sha256(config).hexdigest() + ".json"
    manifest = json.dumps([{"Config": config_name, "RepoTags": [tag], "Layers": ["rootfs/layer.tar"]}]).encode()
    with tarfile.open(out, "w") as archive:
        archive.add(layer, "rootfs/layer.tar")
        for name, data in ((config_name, config), ("manifest.json", manifest)):
            info = tarfile.TarInfo(name)
            info.size = len(data)
            archive.addfile(info, io.BytesIO(data))


def load_layer(dc: docker.DockerClient, layer: Path, tag: str, arch: str, tmp: str) -> None:
    """The rootfs tar as an image that says what it is: `docker import` of
    Docker 20.10 labels every import with the engine's own architecture
    (its --platform sets only the OS), so a foreign rootfs is loaded instead."""
    archive = Path(tmp, "image.tar")
    rootfs_image_archive(layer, tag, arch, archive)
    layer.unlink()
    with open(archive, "rb") as f:
        dc.images.load(f)


def build_image(dc: docker.DockerClient, tag: str, dockerfile: str, files: dict[str, str]) -> None:
    """docker build from an in-memory context; the log goes to .lab/cache/build."""
    context = io.BytesIO()
    with tarfile.open(fileobj=context, mode="w") as tar:
        for name, text in {"Dockerfile": dockerfile, **files}.items():
            data = text.encode()
            info = tarfile.TarInfo(name)
            info.size = len(data)
            info.mode = 0o644
            tar.addfile(info, io.BytesIO(data))
    context.seek(0)
    BUILD_DIR.mkdir(parents=True, exist_ok=True)
    log_path = BUILD_DIR / (tag.replace(":", "_").replace("/", "_") + ".log")
    error = None
    with open(log_path, "w") as log:
        for chunk in dc.api.build(
            fileobj=context, custom_context=True, tag=tag, rm=True, forcerm=True, pull=False, decode=True
        ):
            log.write(chunk.get("stream", "") or json.dumps(chunk) + "\n")
            if "error" in chunk:
                error = chunk["error"].strip()
    if error:
        raise LabError(f"building {tag} failed: {error} (log: {log_path})")


def create_systemd_container(
    dc: docker.DockerClient,
    image: str,
    name: str,
    *,
    hostname: str,
    network: str,
    labels: dict[str, str],
    ports: dict[int, int],
    volumes: dict[str, str],
):
    """Create (not start) a container running systemd as PID 1 on this machine.

    `ports` maps container port -> 127.0.0.1 host port; `volumes` maps a named
    volume or host path -> "container_path[:ro]".

    `--privileged` fails here, so: the capabilities systemd and a nested
    dockerd need; the host's cgroup tree bound rw with the host cgroup
    namespace (the host is cgroup v1 hybrid, and trixie's systemd 257 accepts
    the pre-mounted hybrid tree it finds); and no masked or read-only /proc
    paths (what `--security-opt systempaths=unconfined` does in the CLI,
    which the API lacks), because the nested dockerd writes
    /proc/sys/net/ipv6/conf/*/disable_ipv6 for its containers.
    """
    binds = ["/sys/fs/cgroup:/sys/fs/cgroup:rw"]
    binds += [f"{source}:{target}" for source, target in volumes.items()]
    host_config = dc.api.create_host_config(
        binds=binds,
        port_bindings={f"{c}/tcp": ("127.0.0.1", h) for c, h in ports.items()},
        cap_add=["SYS_ADMIN", "NET_ADMIN", "MKNOD"],
        security_opt=["seccomp=unconfined", "apparmor=unconfined"],
        cgroupns="host",
        tmpfs={"/run": "", "/run/lock": ""},
        network_mode=network,
    )
    host_config["MaskedPaths"] = []
    host_config["ReadonlyPaths"] = []
    created = dc.api.create_container(
        image,
        name=name,
        hostname=hostname,
        labels=labels,
        detach=True,
        ports=list(ports),
        host_config=host_config,
        networking_config=dc.api.create_networking_config({network: dc.api.create_endpoint_config()}),
    )
    return dc.containers.get(created["Id"])
