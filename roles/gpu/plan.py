"""Pure decisions of the gpu role: which host gets what, computed from host
readings and data, so they test without a host.

NVIDIA documents the container toolkit's apt repository as one flat
repository per architecture (``<repo>/stable/deb/$(ARCH) /``) signed by the
key at ``<repo>/gpgkey``; see roles/gpu/__init__.py for the steps."""

from __future__ import annotations

import base64
import re
import shlex

import roles.payload.hooks as payload_hooks
import roles.x11.hooks as x11_hooks
from robotfleet.host import aptrepo
from robotfleet.host import platform as host_platform
from robotfleet.host.platform import PlanError

TOOLKIT = "nvidia-container-toolkit"
RUNTIME_NAME = "nvidia"
RUNTIME_PATH = "nvidia-container-runtime"
TEGRA_RELEASE = "/etc/nv_tegra_release"
SUPPORTED = {"ubuntu": ("jammy", "noble"), "debian": ("bookworm", "trixie")}
DRIVER_MISSING = (
    "gpu: no NVIDIA driver is loaded ({detail}); install the NVIDIA driver first "
    "(this tool does not install kernel drivers), then run again"
)


def wanted(data) -> bool:
    """The gpu role runs where the payload asks for GPUs or the host is a GPU host."""
    return data.get("gpu_vendor") == "nvidia" or payload_hooks.wants_gpus(data)


# --- what the host snapshot tells -------------------------------------------


def readings_probe(driver_version_file: str) -> str:
    """Shell snippet (read-only) printing key=value lines: the driver version
    file's first line, the Jetson release line, nvidia-smi's exit status and
    output (values base64, one line each)."""
    f = shlex.quote(driver_version_file)
    return (
        f'[ -r {f} ] && echo "driver=$(head -n 1 {f} | base64 -w0)"; '
        f'[ -f {TEGRA_RELEASE} ] && echo "tegra=$(head -n 1 {TEGRA_RELEASE} | base64 -w0)"; '
        "if command -v nvidia-smi >/dev/null 2>&1; then "
        'o=$(timeout 20 nvidia-smi -L 2>&1); echo "smi_rc=$?"; '
        'echo "smi=$(printf %s "$o" | head -c 400 | base64 -w0)"; '
        "else echo smi_rc=absent; fi"
    )


def parse_readings(text: str) -> dict[str, str]:
    values = {}
    for line in (text or "").splitlines():
        key, sep, value = line.partition("=")
        if not sep:
            continue
        if key in ("driver", "tegra", "smi"):
            try:
                value = base64.b64decode(value).decode(errors="replace").strip()
            except ValueError:
                value = ""
        values[key] = value
    return values


def driver_version(first_line: str) -> str | None:
    """'NVRM version: NVIDIA UNIX x86_64 Kernel Module  550.54.14  Thu ...' -> '550.54.14'."""
    found = re.search(r"\s(\d+(?:\.\d+)+)(?:\s|$)", first_line)
    return found.group(1) if found else None


def platform(readings: dict[str, str]) -> str:
    """'jetson' (L4T: the toolkit comes with JetPack) or 'desktop'."""
    return "jetson" if "tegra" in readings else "desktop"


def driver_problem(readings: dict[str, str], driver_version_file: str) -> str | None:
    """One line if no NVIDIA driver is usable on a desktop/server GPU host.
    On Jetson the driver is part of L4T's kernel: not checked here."""
    if platform(readings) == "jetson":
        return None
    if "driver" not in readings:
        return DRIVER_MISSING.format(detail=f"{driver_version_file} is absent")
    rc = readings.get("smi_rc", "absent")
    if rc == "absent":
        return DRIVER_MISSING.format(detail="nvidia-smi is not installed")
    if rc != "0":
        said = readings.get("smi", "").splitlines()
        return DRIVER_MISSING.format(detail=f"nvidia-smi failed: {said[0] if said else 'exit ' + rc}")
    return None


# --- the repository ------------------------------------------------------------


def check_os(os_release: dict, arch: str) -> None:
    try:
        dist = host_platform.distribution(os_release)
        codename = (os_release.get("ubuntu_codename") if dist == "ubuntu" else None) or os_release.get(
            "version_codename"
        )
        if codename not in SUPPORTED[dist]:
            raise PlanError(
                f"{dist} {codename or '(unknown release)'} is not supported for the container toolkit "
                f"(supported: {', '.join(SUPPORTED['ubuntu'] + SUPPORTED['debian'])})"
            )
        host_platform.architecture(arch)
    except PlanError as error:
        raise PlanError(f"gpu: {error}") from None


def repo_uri(repo_url: str, channel: str, arch: str) -> str:
    """NVIDIA's flat repository for one architecture: <repo>/<channel>/deb/<arch>."""
    return f"{repo_url.rstrip('/')}/{channel}/deb/{arch}"


def key_url(data_key_url: str | None, repo_url: str) -> str:
    return data_key_url or f"{repo_url.rstrip('/')}/gpgkey"


def sources_text(uri: str, key_path: str) -> str:
    """deb822 form of NVIDIA's one-line source
    ``deb [signed-by=KEY] <repo>/stable/deb/$(ARCH) /`` (a flat repository:
    the suite is "/", no components), with the architecture resolved."""
    return aptrepo.deb822("roles/gpu", uri, "/", key_path)


def package_versions(version: str | None) -> dict[str, str]:
    return {TOOLKIT: version} if version else {}


# --- what the gpu role adds to the docker and payload roles (roles/gpu/__init__.py)


def daemon_options(data, options: dict) -> dict:
    """``options`` with the NVIDIA runtime merged in where the host is a GPU
    host (and ``default-runtime`` when asked).  Added through the docker
    role's hook, so daemon.json keeps one owner and Docker restarts only when
    the result changes.  Runtimes already declared in
    ``docker_daemon_options`` are kept; an explicit ``nvidia`` entry wins."""
    if not wanted(data):
        return options
    merged = dict(options)
    runtimes = dict(merged.get("runtimes") or {})
    runtimes.setdefault(RUNTIME_NAME, {"args": [], "path": RUNTIME_PATH})
    merged["runtimes"] = runtimes
    if data.get("gpu_default_runtime"):
        merged["default-runtime"] = RUNTIME_NAME
    return merged


def payload_environment(data) -> dict[str, str]:
    """What the NVIDIA runtime reads in a GPU payload: which GPUs, and which
    driver parts to inject (graphics too when the host has a display: rviz with GL)."""
    capabilities = data.get("gpu_driver_capabilities")
    if not capabilities:
        capabilities = "compute,utility,graphics" if x11_hooks.has_display(data) else "compute,utility"
    return {
        "NVIDIA_VISIBLE_DEVICES": str(data.get("gpu_visible_devices") or "all"),
        "NVIDIA_DRIVER_CAPABILITIES": capabilities,
    }


RESERVATION = {
    "resources": {"reservations": {"devices": [{"driver": "nvidia", "count": "all", "capabilities": ["gpu"]}]}}
}


def payload_services(data, services: dict) -> dict:
    """Where the payload asks for GPUs: each service gets the NVIDIA
    environment and a device reservation."""
    if not payload_hooks.wants_gpus(data):
        return {}
    return {"*": {"environment": payload_environment(data), "deploy": RESERVATION}}


def check_command(data) -> dict | None:
    """The check payloadctl runs in each payload container once it is
    healthy (the payload's CHECKS hook); None: no GPU check."""
    if not payload_hooks.wants_gpus(data):
        return None
    command = data.get("gpu_check_command")
    return {"command": list(command), "failure": "cannot see a GPU"} if command else None


# --- status -------------------------------------------------------------------


def status_command(data) -> str:
    """One line: '<the driver version file's first line><TAB>yes|no' (yes:
    Docker lists the nvidia runtime)."""
    path = shlex.quote(data.get("gpu_driver_version_file") or "/proc/driver/nvidia/version")
    return (
        f"printf '%s\\t%s\\n' \"$(head -n 1 {path} 2>/dev/null)\" "
        "\"$(docker info -f '{{json .Runtimes}}' 2>/dev/null | grep -q '\"nvidia\"' && echo yes || echo no)\""
    )


def status_cells(output: str) -> dict:
    driver_line, _, runtime = (output.splitlines() or [""])[0].partition("\t")
    driver = driver_version(driver_line)
    runtime = runtime.strip() == "yes"
    # A host with neither a driver nor the runtime is not a GPU host: "-", not "no".
    return {"gpu_driver": driver, "gpu_runtime": runtime if (driver or runtime) else None}
