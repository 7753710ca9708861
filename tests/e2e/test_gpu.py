"""GPU hosts on the simulated fleet, in one deploy of three robots:

- robot3: driver stand-in, the lab's NVIDIA-style repository pinned by its
  key -> key, deb822 source, the stand-in toolkit, the nvidia runtime merged
  into daemon.json, Docker restarted; a rerun changes nothing, Docker is not
  restarted;
- robot2: driver stand-in, but a pinned fingerprint the served key does not
  have -> that host fails, no key, source or toolkit left behind;
- robot1: no driver -> that host fails with one line before anything is
  installed.

What the stand-ins do not prove is in roles/gpu/README.md ("What the lab proves")."""

from __future__ import annotations

import json

import pytest

from tests.lab import nvidia_mirror

WRONG_FPR = "0123456789ABCDEF0123456789ABCDEF01234567"
SOURCES = "/etc/apt/sources.list.d/nvidia-container-toolkit.sources"
KEY = "/etc/apt/keyrings/nvidia-container-toolkit.asc"
GPU_HOSTS = ("robot1", "robot2", "robot3")


def gpu_block(settings: dict, **override) -> str:
    values = {"gpu_vendor": "nvidia", **settings, **override}
    return "".join(f"      {key}: {json.dumps(value)}\n" for key, value in values.items())


def installed(lab, host: str) -> dict:
    checks = {
        "key": f"test -e {KEY}",
        "source": f"test -e {SOURCES}",
        "toolkit": "dpkg-query -W -f='${Status}' nvidia-container-toolkit 2>/dev/null | grep -q 'ok installed'",
        "docker": "command -v dockerd",
    }
    return {name: lab.sh(host, command)[0] == 0 for name, command in checks.items()}


def docker_pid(lab, host: str) -> str:
    return lab.ok(host, "systemctl show -p MainPID --value docker.service").strip()


@pytest.fixture(scope="module")
def gpu_fleet(lab, first_run, tmp_path_factory):  # robot3's daemon.json and payload are the first run's
    settings = nvidia_mirror.lab_settings(lab.state)
    path = lab.fleet_with(
        tmp_path_factory.mktemp("gpu"),
        **{
            "    robot1:\n": "    robot1:\n" + gpu_block(settings),
            "    robot2:\n": "    robot2:\n" + gpu_block(settings, gpu_apt_key_fingerprint=WRONG_FPR),
            "    robot3:\n": "    robot3:\n" + gpu_block(settings),
        },
    )
    for host in ("robot2", "robot3"):
        lab.ok(host, nvidia_mirror.fake_driver_script())
    yield path
    for host in ("robot2", "robot3"):
        lab.sh(host, nvidia_mirror.remove_fake_driver_script())
    # Give robot3 back to the plain lab fleet for the modules that follow.
    restore = lab.provision("--limit", "robot3", label="(gpu: robot3 back to the lab fleet)")
    assert restore.returncode == 0, restore.output[-3000:]


def test_gpu_hosts_repository_key_pin_runtime_and_refusals(lab, gpu_fleet):
    before = {host: installed(lab, host) for host in GPU_HOSTS}
    run = lab.provision(*[a for h in GPU_HOSTS for a in ("--limit", h)], fleet=gpu_fleet, label="(gpu hosts)")
    assert run.failed_hosts == {"robot1", "robot2"}, run.output[-4000:]

    # robot1: no driver -> one line, nothing installed.
    assert "robot1" in run.output and "gpu: no NVIDIA driver is loaded" in run.output
    assert "this tool does not install kernel drivers" in run.output
    assert installed(lab, "robot1") == before["robot1"]
    assert not installed(lab, "robot1")["toolkit"]

    # robot2: the served key is not the pinned one -> nothing of NVIDIA's left.
    # (one message for Docker's and NVIDIA's pinned keys since they share robotfleet/host/aptrepo.py)
    assert f"gpu_apt_key_fingerprint {WRONG_FPR}; key not installed" in run.output
    after2 = installed(lab, "robot2")
    assert not (after2["key"] or after2["source"] or after2["toolkit"])
    assert lab.ok("robot2", "ls -A /etc/apt/keyrings | grep -c robotprov || true").strip() == "0"

    # robot3: exactly the pinned key, NVIDIA's source layout, the stand-in toolkit.
    fingerprint = nvidia_mirror.lab_settings(lab.state)["gpu_apt_key_fingerprint"]
    keys = lab.ok(
        "robot3", f"h=$(mktemp -d); GNUPGHOME=$h gpg --batch --show-keys --with-colons {KEY} 2>/dev/null; rm -rf $h"
    )
    records = [line.split(":") for line in keys.splitlines()]
    assert [r[0] for r in records].count("pub") == 1
    assert [r[9] for r in records if r[0] == "fpr"][0] == fingerprint
    source = lab.ok("robot3", f"cat {SOURCES}")
    assert f"URIs: {nvidia_mirror.lab_settings(lab.state)['gpu_repo_url']}/stable/deb/amd64" in source
    assert "Suites: /" in source and f"Signed-By: {KEY}" in source
    assert nvidia_mirror.VERSION in lab.ok("robot3", "dpkg-query -W -f='${Version}' nvidia-container-toolkit")

    # daemon.json: the runtime merged, the lab's other options kept; Docker serves it.
    daemon = json.loads(lab.ok("robot3", "cat /etc/docker/daemon.json"))
    assert daemon["runtimes"] == {"nvidia": {"args": [], "path": "nvidia-container-runtime"}}
    assert daemon["live-restore"] is True and daemon["insecure-registries"]
    assert "nvidia" in json.loads(lab.ok("robot3", "docker info -f '{{json .Runtimes}}'"))
    image = lab.payload("robot3")["Config"]["Image"]
    said = lab.ok("robot3", f"docker run --rm --runtime nvidia {image} echo through-the-runtime")
    assert said.strip().endswith("through-the-runtime")

    # A rerun: nothing changes and Docker is not restarted.
    pid = docker_pid(lab, "robot3")
    again = lab.provision("--limit", "robot3", fleet=gpu_fleet, label="(gpu host, converged)")
    assert again.returncode == 0, again.output[-3000:]
    assert again.changed_hosts == set()
    assert docker_pid(lab, "robot3") == pid
