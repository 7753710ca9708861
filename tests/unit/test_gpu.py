"""The gpu role: planned commands for GPU hosts (Ubuntu 22.04/24.04, Debian
12/13, amd64/arm64, Jetson), the driver refusal, the daemon.json merge and
the payload's GPU settings.  The key download runs for real in
tests/integration/test_gpu.py."""

import base64
import json

import pytest

from robotfleet.host import aptrepo
from robotfleet.host.snapshot import FileState
from roles.gpu import plan as gpu_plan
from tests.fixtures import IMAGE
from tests.unit.harness import find, fresh_host, plan, written_files

NVIDIA_FPR = "C95B321B61E88C1809C4F759DDCAE044F796ECB0"
GPU_ROBOT = {"payload_image": IMAGE, "gpu_vendor": "nvidia"}
NVRM = "NVRM version: NVIDIA UNIX x86_64 Kernel Module  550.54.14  Thu Feb 22 01:44:30 UTC 2024"
MATRIX = [(o, a) for o in ("ubuntu-22.04", "ubuntu-24.04", "debian-12", "debian-13") for a in ("amd64", "arm64")]
SOURCES = "/etc/apt/sources.list.d/nvidia-container-toolkit.sources"
KEY = "/etc/apt/keyrings/nvidia-container-toolkit.asc"


def b64(text: str) -> str:
    return base64.b64encode(text.encode()).decode()


def readings(driver=NVRM, smi_rc="0", smi="GPU 0: NVIDIA RTX A2000 (UUID: GPU-1234)", tegra=None) -> str:
    lines = []
    if driver is not None:
        lines.append(f"driver={b64(driver)}")
    if tegra is not None:
        lines.append(f"tegra={b64(tegra)}")
    lines.append(f"smi_rc={smi_rc}")
    if smi_rc != "absent":
        lines.append(f"smi={b64(smi)}")
    return "\n".join(lines) + "\n"


def gpu_host(os_name="ubuntu-24.04", arch="amd64", **kwargs):
    snap = fresh_host(os_name, arch)
    snap.probes["gpu_readings"] = readings(**kwargs)
    return snap


def converged(snap, data):
    """``snap`` after a first run: toolkit installed, key and source in place,
    daemon.json with the runtime.  Built from what the first plan wrote."""
    first = plan({"r1": ("robots", data, snap)})["r1"]
    files = written_files(first)
    import hashlib

    for path, text in files.items():
        content = text.encode() if isinstance(text, str) else text
        mode = "600" if path == "/etc/docker/daemon.json" else "644"  # daemon.json is root's alone
        snap.files[path] = FileState("file", hashlib.sha256(content).hexdigest(), mode, "root", "root")
    snap.files[KEY] = FileState("file", "0" * 64, "644", "root", "root")
    return snap, first


@pytest.mark.parametrize("os_name, arch", MATRIX)
def test_gpu_host_gets_nvidias_repository_key_pin_and_toolkit(os_name, arch):
    result = plan({"r1": ("robots", GPU_ROBOT, gpu_host(os_name, arch))})
    commands = result["r1"]
    assert result.failed == set()
    key = find(commands, "nvidia.github.io/libnvidia-container/gpgkey")
    assert len(key) == 1
    assert f"pin={NVIDIA_FPR}" in key[0] and f"dest={KEY}" in key[0]
    assert written_files(commands)[SOURCES].splitlines()[1:] == [
        "Types: deb",
        f"URIs: https://nvidia.github.io/libnvidia-container/stable/deb/{arch}",
        "Suites: /",
        f"Signed-By: {KEY}",
    ]
    install = find(commands, r"--allow-downgrades install nvidia-container-toolkit\b")
    assert len(install) == 1
    # apt update waits for the apt lock like every other apt call (it ran
    # outside the lock helper before, with $(apt_lock_left) undefined).
    update = find(commands, r"apt_locked apt-get -q .* update\n'$")
    assert update and all("apt_lock_timeout=300\n" in c and "apt_lock_left()" in c for c in update)
    docker_install = find(commands, "install docker-ce ")[0]
    # Key and source first, then apt update, then the toolkit, all before Docker.
    assert (
        commands.index(key[0]) < commands.index(update[0]) < commands.index(install[0]) < commands.index(docker_install)
    )
    daemon = json.loads(written_files(commands)["/etc/docker/daemon.json"])
    assert daemon["runtimes"] == {"nvidia": {"args": [], "path": "nvidia-container-runtime"}}
    assert "default-runtime" not in daemon
    assert daemon["live-restore"] is True  # merged, not replaced


def test_payload_gpu_alone_makes_a_gpu_host():
    commands = plan({"r1": ("robots", {"payload_image": IMAGE, "payload_gpu": True}, gpu_host())})["r1"]
    assert find(commands, r"--allow-downgrades install nvidia-container-toolkit\b")


def test_hosts_without_gpu_read_and_install_nothing_of_it():
    result = plan({"r1": ("robots", {"payload_image": IMAGE}, fresh_host("ubuntu-24.04"))})
    assert not find(result["r1"], "nvidia")
    assert "gpu_readings" not in result.queries["r1"]["probes"]
    assert "nvidia" not in json.loads(written_files(result["r1"])["/etc/docker/daemon.json"]).get("runtimes", {})


@pytest.mark.parametrize(
    "kwargs, reason",
    [
        ({"driver": None}, "/proc/driver/nvidia/version is absent"),
        ({"smi_rc": "absent"}, "nvidia-smi is not installed"),
        (
            {"smi_rc": "9", "smi": "NVIDIA-SMI has failed because it couldn't communicate with the NVIDIA driver."},
            "nvidia-smi failed: NVIDIA-SMI has failed because it couldn",
        ),
    ],
)
def test_no_driver_fails_that_host_only_before_anything_is_installed(kwargs, reason):
    result = plan(
        {
            "gpu1": ("robots", GPU_ROBOT, gpu_host(**kwargs)),
            "r2": ("robots", {"payload_image": IMAGE}, fresh_host("ubuntu-24.04")),
        }
    )
    assert result.failed == {"gpu1"}
    assert len(result["gpu1"]) == 1, result["gpu1"]  # the failure, nothing else
    assert reason in result["gpu1"][0]
    assert "this tool does not install kernel drivers" in result["gpu1"][0]
    assert find(result["r2"], "install docker-ce ")


def test_driver_version_file_is_a_setting():
    snap = gpu_host()
    data = {**GPU_ROBOT, "gpu_driver_version_file": "/etc/lab/nvidia-version"}
    result = plan({"r1": ("robots", data, snap)})
    assert "/etc/lab/nvidia-version" in result.queries["r1"]["probes"]["gpu_readings"]


def test_jetson_uses_jetpacks_toolkit_and_adds_no_desktop_repository():
    snap = gpu_host(
        "ubuntu-22.04",
        "arm64",
        driver=None,
        smi_rc="absent",
        tegra="# R36 (release), REVISION: 4.3, GCID: 38968081, BOARD: generic, EABI: aarch64",
    )
    result = plan({"jet": ("robots", GPU_ROBOT, snap)})
    commands = result["jet"]
    assert result.failed == set()
    assert not find(commands, "libnvidia-container")
    assert SOURCES not in written_files(commands)
    assert find(commands, r"install nvidia-container-toolkit")
    assert "nvidia" in json.loads(written_files(commands)["/etc/docker/daemon.json"])["runtimes"]


def test_converged_gpu_host_sends_nothing():
    snap, _ = converged(gpu_host(), GPU_ROBOT)
    snap.packages.update({"nvidia-container-toolkit": "1.17.8-1", "gpg": "2"})
    snap.probes["gpu_key_fingerprints"] = f"{NVIDIA_FPR}\n{aptrepo.CANONICAL}\n"
    commands = plan({"r1": ("robots", GPU_ROBOT, snap)})["r1"]
    assert not find(commands, "nvidia"), commands
    assert not find(commands, "daemon.json")
    assert not find(commands, "systemctl restart docker")


@pytest.mark.parametrize(
    "probe",
    [
        f"{NVIDIA_FPR}\n{'A' * 40}\n{aptrepo.CANONICAL}\n",  # an extra primary key
        f"{NVIDIA_FPR}\n",  # only the pinned key as gpg reads it, but not gpg's export of it: a hidden block
        f"{aptrepo.CANONICAL}\n",  # nothing gpg can read
    ],
)
def test_keyring_other_than_the_pinned_key_as_gpg_exports_it_is_replaced(probe):
    snap, _ = converged(gpu_host(), GPU_ROBOT)
    snap.packages.update({"nvidia-container-toolkit": "1.17.8-1", "gpg": "2"})
    snap.probes["gpu_key_fingerprints"] = probe
    commands = plan({"r1": ("robots", GPU_ROBOT, snap)})["r1"]
    assert len(find(commands, "libnvidia-container/gpgkey")) == 1
    assert find(commands, r"update\n'$")


def test_default_runtime_version_pin_and_mirror():
    data = {
        **GPU_ROBOT,
        "gpu_default_runtime": True,
        "gpu_toolkit_version": "1.17.8-1",
        "gpu_repo_url": "http://mirror.lan/nvidia",
        "gpu_apt_key_url": "http://mirror.lan/nvidia.asc",
    }
    commands = plan({"r1": ("robots", data, gpu_host("debian-12", "arm64"))})["r1"]
    assert find(commands, "url=http://mirror.lan/nvidia.asc\n(.|\n)*curl ")
    assert "URIs: http://mirror.lan/nvidia/stable/deb/arm64" in written_files(commands)[SOURCES]
    assert find(commands, "install nvidia-container-toolkit=1.17.8-1 ")
    assert json.loads(written_files(commands)["/etc/docker/daemon.json"])["default-runtime"] == "nvidia"


def test_runtime_change_restarts_docker_once_and_only_then():
    snap, first = converged(gpu_host(), GPU_ROBOT)
    assert len(find(first, "systemctl restart docker.service")) == 1
    snap.packages.update({"nvidia-container-toolkit": "1", "gpg": "2"})
    snap.probes["gpu_key_fingerprints"] = f"{NVIDIA_FPR}\n{aptrepo.CANONICAL}\n"
    again = plan({"r1": ("robots", {**GPU_ROBOT, "gpu_default_runtime": True}, snap)})["r1"]
    assert len(find(again, "systemctl restart docker.service")) == 1


def test_daemon_options_merge_keeps_other_runtimes_and_explicit_entry():
    data = {"gpu_vendor": "nvidia"}
    options = {"runtimes": {"crun": {"path": "/usr/bin/crun"}, "nvidia": {"path": "/opt/nv/runtime"}}}
    merged = gpu_plan.daemon_options(data, options)
    assert merged["runtimes"] == options["runtimes"]
    assert gpu_plan.daemon_options({"gpu_vendor": None}, options) is options
    assert gpu_plan.daemon_options(data, {})["runtimes"]["nvidia"]["path"] == "nvidia-container-runtime"


def test_payload_environment_adds_graphics_with_a_display():
    assert gpu_plan.payload_environment({"x11_enabled": False}) == {
        "NVIDIA_VISIBLE_DEVICES": "all",
        "NVIDIA_DRIVER_CAPABILITIES": "compute,utility",
    }
    environment = gpu_plan.payload_environment({"x11_enabled": True})
    assert environment["NVIDIA_DRIVER_CAPABILITIES"] == "compute,utility,graphics"
    assert gpu_plan.payload_environment({"gpu_visible_devices": "0", "gpu_driver_capabilities": "all"}) == {
        "NVIDIA_VISIBLE_DEVICES": "0",
        "NVIDIA_DRIVER_CAPABILITIES": "all",
    }


def test_driver_version_from_the_nvrm_line():
    assert gpu_plan.driver_version(NVRM) == "550.54.14"
    assert (
        gpu_plan.driver_version("NVRM version: NVIDIA UNIX Open Kernel Module for x86_64  570.86.15  Release Build")
        == "570.86.15"
    )
    assert gpu_plan.driver_version("") is None


def test_gpu_payload_gets_environment_reservation_and_check_command():
    from tests.unit.harness import desired_compose, merged, release_spec

    data = merged("laptops", {"payload_image": IMAGE, "x11_user": "alice", "payload_gpu": True})
    service = desired_compose(data, "h")["services"]["payload"]
    assert service["environment"]["NVIDIA_VISIBLE_DEVICES"] == "all"
    assert service["environment"]["NVIDIA_DRIVER_CAPABILITIES"] == "compute,utility,graphics"
    assert service["deploy"]["resources"]["reservations"]["devices"][0]["capabilities"] == ["gpu"]
    assert release_spec(data, {}).checks == [{"command": ["nvidia-smi", "-L"], "failure": "cannot see a GPU"}]
    plain = merged("robots", {"payload_image": IMAGE})
    assert release_spec(plain, {}).checks == []
    assert "NVIDIA_VISIBLE_DEVICES" not in desired_compose(plain, "h")["services"]["payload"]["environment"]
