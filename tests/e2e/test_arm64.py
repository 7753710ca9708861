"""An arm64 robot for real: pi1, an emulated Debian 13 arm64 host (qemu-user
through binfmt_misc: `uname -m` says aarch64), provisioned with robot1
(amd64) in one pyinfra run from one fleet file, each running its own
platform's variant of one multi-platform tag; then pull, a rerun that changes
nothing, and a refused single-platform amd64 image, all checked from inside
the hosts.

pi1 joins the session's lab for this module only (`hosts.up(...,
arm64_robots=1)` reuses its services, mirror and registry; the module's end
removes pi1 and its volumes, so the other modules see the lab as before).
It runs last in its session (tests/e2e/conftest.py; in the test command, last
in its lab group, tests/e2e/groups.py), while its host image, when its
recipe changed, was built in the background from the session's start; it
runs after the session's first run, so robot1 arrives converged and
changes nothing; pi1 is provisioned from nothing.  The first run sends pi1
its payload by push (inventories/lab.yaml with pi1's delivery set to push),
so the bytes sent are the whole arm64 variant, measured against both
variants' layers in the registry; the second run is lab.yaml itself (pull:
Docker picks the arm64 variant).

What the emulation cannot do:
  - Debian's arm64 runc cannot start a container under qemu-user: `runc
    init` clones its first child with CLONE_PARENT (then namespaces with
    CLONE_NEW*) and qemu-user's clone() accepts only fork-like flags (EINVAL),
    so `docker run --runtime runc` fails with "runc create failed: unable to
    start container process: waiting for init preliminary setup: read init-p:
    connection reset by peer" (test_emulated_runc_cannot_start_a_container
    proves both).  The lab copies an amd64 runc into pi1 (the kernel runs it
    natively; the container's arm64 programs run through binfmt_misc) and
    lab.yaml makes it pi1's default runtime: so the payload, its health gate
    and its unit run for real here, but the arm64 runc a real Raspberry Pi or
    Jetson uses is not what starts them (tests/lab/native_runc.py).
  - Docker's network-namespace hook re-runs dockerd's own binary, which
    under emulation is qemu: only host-network containers start (the
    payload's default, payload_network_mode: host); bridge networking on
    arm64 is unit-tested only.  qemu-user has no netfilter sockets either:
    pi1's Docker runs with "iptables": false.
  - udev: no udevd runs in the lab hosts, so the rules are installed and
    checked with (arm64) `udevadm verify`, not triggered; X11: the cookie
    hook is installed, not run by a login (tests/e2e/test_x11.py runs it on
    the amd64 laptop).
  - `exec format error`: the lab's image for it says amd64, so pi1 refuses
    it before the switch; it is run on robot1 instead, whose kernel refuses
    its program (an ELF for no machine) as a robot's would.

Module cost, measured on 2 shared CPUs with the images built and a warm apt
cache (another lab's tests running beside it): pi1 boots in 12-14 s (the
amd64 runc is fetched once into .lab/cache, 4 s), the first run (pi1 from
nothing, robot1 converged) 124-129 s, the pull run 30-31 s, the counted
rerun 7 s, the refusal 11-13 s: 210-220 s in all, the session's lab and
first run excluded.  Building the arm64 host image, when its recipe changed,
adds about 4.5 min (cached by recipe, like the amd64 one).
"""

from __future__ import annotations

import json
import os
import subprocess
import time
import urllib.request

import pytest
import yaml

from tests.bench.roundtrips import COUNTING
from tests.e2e.conftest import BACKGROUND, ROOT, Lab, phase
from tests.fixtures import pyinfra_argv

pytestmark = [pytest.mark.e2e, pytest.mark.arm64]

PI, NUC = "pi1", "robot1"
LIMIT = ("--limit", PI, "--limit", NUC)
PAYLOAD_DIR = "/var/lib/robot-payload"
OCI_INDEX = "application/vnd.oci.image.index.v1+json"
REFUSED = "payload: pi1 is linux/arm64 but image {ref} is linux/amd64 only: refused before anything switched"
QEMU_RUNC_ERROR = (
    "runc create failed: unable to start container process: waiting for init preliminary setup: "
    "read init-p: connection reset by peer"
)
# The clone() calls runc init makes, from Python (arm64 syscall number 220).
CLONE_PROBE = r"""
import ctypes, errno, os
libc = ctypes.CDLL(None, use_errno=True)
for name, flags in (("fork", 17), ("CLONE_PARENT", 0x8000 | 17), ("CLONE_NEWNS", 0x20000 | 17)):
    pid = libc.syscall(220, flags, 0, 0, 0, 0)
    if pid == 0:
        os._exit(0)
    print(name, errno.errorcode[ctypes.get_errno()] if pid < 0 else "ok")
"""


def native_sizes(lab) -> dict[str, int]:
    hosts = [h for h in lab.state["hosts"] if h.get("arch", "amd64") == "amd64"]
    return {
        "robots": sum(h["group"] == "robots" for h in hosts),
        "laptops": sum(h["group"] == "laptops" for h in hosts),
    }


@pytest.fixture(scope="module")
def arm(lab, first_run):
    """The session's lab with pi1 beside its hosts, for this module."""
    from tests.lab import hosts

    if "arm64 host image" in BACKGROUND:
        BACKGROUND.pop("arm64 host image").wait()
    sizes = native_sizes(lab)
    started = time.monotonic()
    state = hosts.up(lab.prefix, **sizes, arm64_robots=1)
    phase("lab: pi1 (emulated arm64) booted", started)
    yield Lab(state)
    hosts.up(lab.prefix, **sizes, arm64_robots=0)  # pi1 and its volumes removed


def pi1_fleet(arm, tmp_path, image: str, delivery: str):
    """inventories/lab.yaml with pi1's payload image and delivery set."""
    return arm.fleet_with(
        tmp_path,
        **{
            "      x11_enabled: true\n": f"      x11_enabled: true\n      payload_delivery: {delivery}\n"
            f'      payload_image: "{image}"\n'
        },
    )


@pytest.fixture(scope="module")
def provisioned(arm, tmp_path_factory):
    """The one run: pi1 from nothing (its payload by push), robot1 as the
    session left it."""
    pushed = f"{arm.state['registry_local']}/ros/payload:1.0"
    fleet = pi1_fleet(arm, tmp_path_factory.mktemp("arm64"), pushed, "push")
    run = arm.provision(*LIMIT, fleet=fleet, label="(pi1 from nothing by push, robot1)")
    assert run.returncode == 0, run.output[-6000:]
    return {"run": run, "pushed": pushed, "push_log": arm.ok(PI, f"cat {PAYLOAD_DIR}/push.log")}


def registry_manifest(lab, ref: str, accept: str) -> dict:
    request = urllib.request.Request(
        f"http://{lab.state['registry_local']}/v2/ros/payload/manifests/{ref}", headers={"Accept": accept}
    )
    with urllib.request.urlopen(request, timeout=10) as answer:
        return json.load(answer)


def variants(lab, tag: str) -> dict[str, dict]:
    """{architecture: {"layers": bytes of its layer blobs, "config": bytes}} of a tag's index."""
    found = {}
    for entry in registry_manifest(lab, tag, OCI_INDEX)["manifests"]:
        manifest = registry_manifest(lab, entry["digest"], entry["mediaType"])
        found[entry["platform"]["architecture"]] = {
            "layers": sum(layer["size"] for layer in manifest["layers"]),
            "config": manifest["config"]["size"],
        }
    return found


def running(lab, host: str, ref: str, platform: str, version: str) -> dict:
    """The host's release of ``ref`` is active and its container healthy,
    running ``platform``'s variant; returns the container."""
    record = lab.record(host)
    assert record["state"] == "active" and record["images"][ref]["platform"] == platform, record
    container = lab.payload(host)
    assert container["State"]["Health"]["Status"] == "healthy"
    assert container["Config"]["Labels"]["org.opencontainers.image.version"] == version
    assert lab.ok(host, f"docker exec {container['Id']} uname -m").strip() == (
        "aarch64" if "arm64" in platform else "x86_64"
    )
    image = json.loads(lab.ok(host, f"docker image inspect {record['images'][ref]['id']}"))[0]
    assert image["Architecture"] == platform.split("/")[1]
    return container


def test_one_run_provisions_the_arm64_and_the_amd64_robot(arm, provisioned):
    run = provisioned["run"]
    assert run.failed_hosts == set()
    assert PI in run.changed_hosts
    assert run.changes(NUC) == []  # converged by the session's first run
    assert arm.ok(PI, "uname -m; dpkg --print-architecture").split() == ["aarch64", "arm64"]
    assert arm.ok(NUC, "uname -m; dpkg --print-architecture").split() == ["x86_64", "amd64"]


def test_docker_ce_for_each_architecture_from_the_mirror(arm, provisioned):
    for host, arch in ((PI, "arm64"), (NUC, "amd64")):
        sources = arm.ok(host, "cat /etc/apt/sources.list.d/docker.sources")
        assert f"URIs: {arm.state['mirror_url']}/debian" in sources and f"Architectures: {arch}\n" in sources
        packages = arm.ok(
            host,
            "dpkg-query -W -f '${Package} ${Architecture} ${Status}\\n' "
            "docker-ce docker-ce-cli containerd.io docker-compose-plugin",
        ).splitlines()
        assert len(packages) == 4 and all(line.endswith(f" {arch} install ok installed") for line in packages), packages
        assert arm.ok(host, "docker version -f '{{.Server.Arch}}'").strip() == arch
        assert arm.ok(host, "systemctl is-active docker").strip() == "active"
    daemon = json.loads(arm.ok(PI, "cat /etc/docker/daemon.json"))
    assert daemon["iptables"] is False and daemon["insecure-registries"] == [arm.state["registry"]]
    assert daemon["default-runtime"] == "lab-native-runc"  # lab only: tests/lab/native_runc.py


def test_users_udev_and_x11_on_pi1(arm, provisioned):
    for user in ("ops", "ros"):
        assert "docker" in arm.ok(PI, f"id -nG {user}").split()
    rules = arm.ok(PI, "cat /etc/udev/rules.d/70-robot-sensors.rules")
    assert 'ATTRS{idVendor}=="2341", ATTRS{idProduct}=="0043", SYMLINK+="robot/imu"' in rules
    arm.ok(PI, "udevadm verify --resolve-names=never /etc/udev/rules.d/70-robot-sensors.rules")
    assert arm.ok(PI, "dpkg-query -W -f '${Architecture}' xauth") == "arm64"
    arm.ok(
        PI,
        "test -x /usr/local/bin/robot-x11-cookie && test -f /etc/X11/Xsession.d/90robot-x11-cookie "
        "&& test -f /etc/xdg/autostart/robot-x11-cookie.desktop",
    )
    assert arm.ok(PI, "stat -c '%a %U' /var/lib/robot-x11/ros").split() == ["700", "ros"]


def test_each_robot_runs_its_own_platforms_payload(arm, provisioned):
    running(arm, NUC, f"{arm.state['registry']}/ros/payload:1.0", "linux/amd64", "1.0")
    container = running(arm, PI, provisioned["pushed"], "linux/arm64/v8", "1.0")
    assert arm.ok(PI, "systemctl is-enabled robot-payload; systemctl is-active robot-payload").split() == [
        "enabled",
        "active",
    ]
    assert {d["PathOnHost"] for d in container["HostConfig"]["Devices"]} == {"/dev/robot/imu"}
    assert container["HostConfig"]["NetworkMode"] == "host"
    service = yaml.safe_load(arm.ok(PI, f"cat {PAYLOAD_DIR}/current/compose.yaml"))["services"]["payload"]
    assert service["environment"]["DISPLAY"] == ":0"
    assert "/var/lib/robot-x11/ros:/tmp/.robot-x11:ro" in service["volumes"]


def test_push_sent_pi1_only_the_arm64_variant(arm, provisioned):
    """pi1 had no payload image: the bytes sent are the whole arm64 variant
    (its layer blobs and config, in a `docker load` archive), not amd64's."""
    sizes = variants(arm, "1.0")
    arm64, amd64 = sizes["arm64"], sizes["amd64"]
    (line,) = provisioned["push_log"].splitlines()
    words = line.split()
    sent, full = int(words[4]), int(words[6])
    print(f"\n[e2e] push to pi1: {line}; registry: arm64 layers {arm64['layers']} B, amd64 layers {amd64['layers']} B")
    assert line.endswith(" 2 of 2 layers, linux/arm64/v8 from the registry"), line
    # "of" counts the variant's blobs; "sent" is the archive: those blobs,
    # its manifest.json and the tar headers.
    assert full == arm64["layers"] + arm64["config"], (full, arm64)
    assert full < sent < full + 16 * 1024, (sent, full)
    assert sent < amd64["layers"], (sent, amd64)


def test_emulated_runc_cannot_start_a_container(arm, provisioned):
    """Why the lab gives pi1 a native runc: Debian's arm64 runc, emulated,
    fails at runc init's clone(CLONE_PARENT), which qemu-user refuses."""
    image = arm.record(PI)["images"][provisioned["pushed"]]["id"]
    code, output = arm.sh(PI, f"docker run --rm --runtime runc --network host {image} true")
    assert code == 125 and QEMU_RUNC_ERROR in output, output
    arm.ok(PI, f"cat > /root/clone.py <<'EOF'\n{CLONE_PROBE}EOF")
    assert arm.ok(PI, "python3 /root/clone.py").split() == [
        "fork",
        "ok",
        "CLONE_PARENT",
        "EINVAL",
        "CLONE_NEWNS",
        "EINVAL",
    ]


def test_pull_gets_pi1_the_arm64_variant_of_the_tag(arm, provisioned):
    """lab.yaml itself: pi1 pulls the multi-platform tag and Docker picks arm64."""
    run = arm.provision(*LIMIT, label="(pi1 by pull, robot1)")
    assert run.returncode == 0, run.output[-4000:]
    assert run.changed_hosts == {PI}
    running(arm, PI, f"{arm.state['registry']}/ros/payload:1.0", "linux/arm64/v8", "1.0")


def test_a_rerun_changes_nothing_in_one_ssh_command_per_host(arm, provisioned):
    report = ROOT / ".lab" / arm.prefix / "arm64-roundtrips.json"
    env = dict(os.environ, ROBOT_LAB_PREFIX=arm.prefix, PYINFRA_PROGRESS="off")
    started = time.monotonic()
    proc = subprocess.run(
        pyinfra_argv(str(report), "-y", "--json", "inventories/lab.py", "deploy.py", *LIMIT, setup=COUNTING),
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
    )
    phase(f"pyinfra deploy.py (pi1 and robot1: rerun, counted) (exit {proc.returncode})", started)
    assert proc.returncode == 0, (proc.stderr + proc.stdout)[-4000:]
    results = json.loads(proc.stdout)["results"]
    assert {host for op in results["operations"] for host in op["success"] + op["error"]} == set()
    counts = json.loads(report.read_text())
    assert {host: counts[host]["commands"] for host in (PI, NUC)} == {PI: 1, NUC: 1}


def test_an_amd64_only_image_is_refused_on_pi1_before_any_switch(arm, provisioned, tmp_path):
    ref = f"{arm.state['registry']}/ros/payload:1.0-amd64"
    current = arm.ok(PI, f"readlink {PAYLOAD_DIR}/current")
    releases = arm.ok(PI, f"ls {PAYLOAD_DIR}/releases")
    container = arm.payload(PI)["Id"]
    run = arm.provision("--limit", PI, fleet=pi1_fleet(arm, tmp_path, ref, "pull"), label="(pi1: amd64-only image)")
    assert run.returncode != 0  # pi1 was the one host: "No hosts remaining", no results
    assert REFUSED.format(ref=ref) in run.output, run.output[-4000:]
    assert arm.ok(PI, f"readlink {PAYLOAD_DIR}/current") == current
    assert arm.ok(PI, f"ls {PAYLOAD_DIR}/releases") == releases
    assert arm.payload(PI)["Id"] == container and arm.payload(PI)["State"]["Health"]["Status"] == "healthy"


def test_a_payload_built_for_another_machine_is_named_by_the_health_gate_and_rolled_back(arm, provisioned, tmp_path):
    """On robot1 (amd64): 1.3-exec-format says linux/amd64, so it passes the
    platform check, but its program is an ELF for no machine this kernel runs
    (binfmt_misc would run an arm64 one under emulation here, and a robot's
    kernel would refuse it the same way): exec format error, named, and the
    old release back."""
    ref = f"{arm.state['registry']}/ros/payload:1.3-exec-format"
    current = arm.ok(NUC, f"readlink {PAYLOAD_DIR}/current")
    fleet = arm.fleet_with(tmp_path, **{"    robot1:\n": f'    robot1:\n      payload_image: "{ref}"\n'})
    run = arm.provision("--limit", NUC, fleet=fleet, label="(robot1: a payload built for another machine)")
    assert run.returncode != 0
    assert "cannot run: exec format error: its program is not built for this robot's architecture" in run.output, (
        run.output[-4000:]
    )
    assert arm.ok(NUC, f"readlink {PAYLOAD_DIR}/current") == current
    container = arm.payload(NUC)
    assert container["State"]["Health"]["Status"] == "healthy"
    assert container["Config"]["Labels"]["org.opencontainers.image.version"] == "1.0"
