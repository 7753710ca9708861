"""End to end (issue 13): the payload as a compose project of two services
(ros/payload with a HEALTHCHECK, ros/driver without), one release for the
whole project, `docker compose config` on the robot, and taking over robots
whose payload was started another way (`docker run --restart always`, a
foreign compose project), through a Docker restart and a reboot."""

from __future__ import annotations

import json
import subprocess
import time

import pytest

from tests.e2e.conftest import wait_for
from tests.e2e.twoservices import SECRET, SECRET_FILE, two_services

pytestmark = pytest.mark.e2e

ALL_TAG = '    payload_image: "@registry@/ros/payload:1.0"\n'
PROJECT = "robot-payload"


def services_of(lab, host: str) -> dict[str, dict]:
    """service -> docker inspect of the project's running containers."""
    ids = lab.ok(host, f"docker ps -q --filter label=com.docker.compose.project={PROJECT}").split()
    inspected = json.loads(lab.ok(host, "docker inspect " + " ".join(ids))) if ids else []
    return {c["Config"]["Labels"]["com.docker.compose.service"]: c for c in inspected}


def version(container: dict) -> str:
    return container["Config"]["Labels"]["org.opencontainers.image.version"]


def running_payloads(lab, host: str) -> list[str]:
    """Names of running containers of the ros/payload image repository."""
    lines = lab.ok(host, "docker ps --format '{{.Names}} {{.Image}}'").splitlines()
    return sorted(line.split()[0] for line in lines if "/ros/payload" in line)


def failed_alone(run, host: str) -> bool:
    """The one host of a --limit run failed (pyinfra then prints no JSON results)."""
    return run.returncode != 0 and (
        run.failed_hosts == {host}
        or (run.results is None and "No hosts remaining" in run.output and f"[{host}]  Error" in run.output)
    )


def limits(*hosts: str) -> list[str]:
    return [arg for host in hosts for arg in ("--limit", host)]


@pytest.fixture(scope="module")
def fleet(lab, first_run, tmp_path_factory):
    def make(all_vars: str, **more: str):
        return lab.fleet_with(tmp_path_factory.mktemp("fleet"), **{ALL_TAG: all_vars, **more})

    yield make
    SECRET_FILE.unlink(missing_ok=True)


def test_two_service_payload_deploys(lab, fleet):
    run = lab.provision(*limits("robot1", "robot2", "laptop1"), fleet=fleet(two_services()), label="(two services)")
    assert run.returncode == 0, run.output[-4000:]
    for host in ("robot1", "robot2"):
        running = services_of(lab, host)
        assert set(running) == {"payload", "driver"}
        assert running["payload"]["State"]["Health"]["Status"] == "healthy"
        assert "Health" not in running["driver"]["State"]  # no HEALTHCHECK: gated on running without restarts
        assert version(running["payload"]) == "1.1" and version(running["driver"]) == "driver-1.0"
        assert running["payload"]["HostConfig"]["IpcMode"] == "host"
        assert running["payload"]["HostConfig"]["CapAdd"] in (["CAP_NET_ADMIN"], ["NET_ADMIN"])
        record = lab.record(host)
        assert record["state"] == "active"
        for image in record["images"].values():
            assert "@sha256:" in image["pinned"]
        assert {ref.rsplit("/", 2)[-2] + "/" + ref.rsplit("/", 1)[-1] for ref in record["images"]} == {
            "ros/payload:1.1",
            "ros/driver:1.0",
        }
    # The sensors go to the service that asked for devices.
    devices = [d["PathOnHost"] for d in services_of(lab, "robot1")["driver"]["HostConfig"]["Devices"]]
    assert sorted(devices) == ["/dev/robot/back_camera", "/dev/robot/front_camera", "/dev/robot/lidar"]
    assert not services_of(lab, "robot1")["payload"]["HostConfig"]["Devices"]
    status = json.loads(
        lab.ok(
            "robot1",
            "python3 /usr/local/lib/robot-payload/payloadctl status --dir /var/lib/robot-payload --name robot-payload",
        )
    )
    assert {k: (v["state"], v["health"]) for k, v in status["services"].items()} == {
        "payload": ("running", "healthy"),
        "driver": ("running", None),
    }
    # The secret file (issue 50, item 3): on the robot 0600 root's, read by every service, in no compose file.
    assert lab.ok("robot1", "stat -c '%a %U:%G' /var/lib/robot-payload/secrets/db_password").strip() == "600 root:root"
    for container in services_of(lab, "robot1").values():
        assert lab.ok("robot1", f"docker exec {container['Id']} cat /run/secrets/db_password").strip() == SECRET
    assert SECRET not in lab.ok("robot1", "cat /var/lib/robot-payload/current/compose.yaml")
    # The laptop has the same project staged for development.
    staged = json.loads(lab.ok("laptop1", "sed 1d /var/lib/robot-payload/current/compose.yaml"))
    assert set(staged["services"]) == {"payload", "driver"}
    assert lab.record("laptop1")["state"] == "staged"


def test_one_service_s_new_tag_leaves_the_other_running(lab, fleet):
    before = services_of(lab, "robot1")
    robot1_driver = '    robot1:\n      payload_services: {driver: {image: "@registry@/ros/driver:1.1"}}\n'
    run = lab.provision(
        *limits("robot1", "robot2"),
        fleet=fleet(two_services(), **{"    robot1:\n": robot1_driver}),
        label="(robot1 driver 1.1)",
    )
    assert run.returncode == 0, run.output[-4000:]
    assert run.changed_hosts == {"robot1"}  # robot2 converged: nothing sent but the snapshot
    after = services_of(lab, "robot1")
    assert version(after["driver"]) == "driver-1.1" and after["driver"]["Id"] != before["driver"]["Id"]
    assert after["payload"]["Id"] == before["payload"]["Id"]  # compose left it running
    assert after["payload"]["State"]["StartedAt"] == before["payload"]["State"]["StartedAt"]


def test_a_failing_service_rolls_the_whole_project_back(lab, fleet):
    before = lab.record("robot1")["id"]
    run = lab.provision(
        *limits("robot1"),
        fleet=fleet(two_services(payload="1.2-broken", driver="1.0")),
        label="(robot1 payload broken, driver 1.0)",
    )
    assert failed_alone(run, "robot1"), run.output[-3000:]
    line = next(x for x in run.output.splitlines() if "[robot1]" in x and "payload: release" in x)
    assert "unhealthy" in line and f"rolled back to {before} and it is running" in line
    assert lab.record("robot1")["id"] == before
    running = services_of(lab, "robot1")
    assert version(running["payload"]) == "1.1" and version(running["driver"]) == "driver-1.1"
    assert running["payload"]["State"]["Health"]["Status"] == "healthy"


def test_compose_config_refusal_on_the_robot_fails_before_anything_switches(lab, fleet):
    before_record = lab.record("robot1")["id"]
    before_ids = {k: c["Id"] for k, c in services_of(lab, "robot1").items()}
    releases = lab.ok("robot1", "ls /var/lib/robot-payload/releases")
    # Valid for the Compose Specification; only the robot knows the file is missing.
    missing = ", env_file: [/etc/robot-payload-missing.env]"
    run = lab.provision(
        *limits("robot1"),
        fleet=fleet(two_services(driver="1.0", driver_extra=missing)),
        label="(robot1 env_file missing)",
    )
    assert failed_alone(run, "robot1"), run.output[-3000:]
    assert "docker compose config refused the release (nothing switched)" in run.output
    assert "robot-payload-missing.env" in run.output
    assert lab.record("robot1")["id"] == before_record
    assert {k: c["Id"] for k, c in services_of(lab, "robot1").items()} == before_ids
    assert lab.ok("robot1", "ls /var/lib/robot-payload/releases") == releases


def test_push_delivery_sends_every_image_of_the_project(lab, fleet):
    import docker

    engine = docker.from_env()
    for repository in ("ros/payload", "ros/driver"):
        engine.images.get(f"{repository}:1.1").tag(f"offline.invalid/{repository}", "1.1")
    offline = (
        "    payload_image: null\n"
        "    payload_delivery: push\n"
        "    payload_services:\n"
        "      payload: {image: offline.invalid/ros/payload:1.1, stop_grace_period: 3s}\n"
        "      driver: {image: offline.invalid/ros/driver:1.1, devices: [], stop_grace_period: 3s}\n"
    )
    lab.ok("robot1", "rm -f /var/lib/robot-payload/push.log")
    run = lab.provision(*limits("robot1"), fleet=fleet(offline), label="(robot1 two images by push)")
    assert run.returncode == 0, run.output[-3000:]
    sent = lab.ok("robot1", "cat /var/lib/robot-payload/push.log").splitlines()
    assert sorted(line.split()[1] for line in sent) == [
        "offline.invalid/ros/driver:1.1",
        "offline.invalid/ros/payload:1.1",
    ]
    running = services_of(lab, "robot1")
    assert version(running["payload"]) == "1.1" and version(running["driver"]) == "driver-1.1"
    again = lab.provision(*limits("robot1"), fleet=fleet(offline), label="(robot1 by push, again)")
    assert again.returncode == 0 and again.changed_hosts == set()
    assert lab.ok("robot1", "cat /var/lib/robot-payload/push.log").splitlines() == sent


FOREIGN_COMPOSE = """\
services:
  ros:
    image: {registry}/ros/payload:1.0
    container_name: ros_payload
    restart: always
    network_mode: host
"""


def set_up_another_way(lab, host: str, how: str) -> None:
    """Our payload gone (as on a robot we never provisioned), theirs running."""
    lab.ok(
        host,
        "systemctl disable --now robot-payload.service && rm -f /etc/systemd/system/robot-payload.service"
        " && systemctl daemon-reload && rm -rf /var/lib/robot-payload",
    )
    lab.ok(host, "docker rm -f ros_payload ros_payload_copy >/dev/null 2>&1; true")  # a rerun on a kept lab
    registry = lab.state["registry"]
    if how == "docker run":
        lab.ok(host, f"docker run -d --restart always --name ros_payload {registry}/ros/payload:1.0")
    else:
        lab.ok(
            host,
            "mkdir -p /opt/rosapp && cat > /opt/rosapp/compose.yaml <<'EOF'\n"
            + FOREIGN_COMPOSE.format(registry=registry)
            + "EOF\n"
            "docker compose -p rosapp -f /opt/rosapp/compose.yaml up -d",
        )
    assert running_payloads(lab, host) == ["ros_payload"]


def foreign_state(lab, host: str, name: str = "ros_payload") -> tuple[str, str]:
    c = json.loads(lab.ok(host, f"docker inspect {name}"))[0]
    return c["State"]["Status"], c["HostConfig"]["RestartPolicy"]["Name"]


def test_takeover_of_robots_set_up_another_way(lab, fleet):
    set_up_another_way(lab, "robot3", "docker run")
    set_up_another_way(lab, "robot2", "compose")

    # A first release that fails gives the robot back as it was.
    failed = lab.provision(
        *limits("robot3"),
        fleet=fleet('    payload_image: "@registry@/ros/payload:1.2-broken"\n'),
        label="(robot3 first release broken)",
    )
    assert failed_alone(failed, "robot3"), failed.output[-3000:]
    assert "taking over what runs the payload another way" in failed.output and "ros_payload" in failed.output
    assert "restored what it had taken over: ros_payload" in failed.output
    assert foreign_state(lab, "robot3") == ("running", "always")
    assert running_payloads(lab, "robot3") == ["ros_payload"]

    # robot2's old setup was a compose project: taken over only because payload_replaces names it (issue 27.2).
    good = fleet(
        '    payload_image: "@registry@/ros/payload:1.1"\n',
        **{
            "    robot2:\n      udev_sensors:": (
                '    robot2:\n      payload_replaces: ["project:rosapp"]\n      udev_sensors:'
            ),
        },
    )
    run = lab.provision(*limits("robot2", "robot3"), fleet=good, label="(takeover robot2, robot3)")
    assert run.returncode == 0, run.output[-4000:]
    assert (
        "[robot3] payload: taking over what runs the payload another way (stopped, restart policy no): "
        f"ros_payload ({lab.state['registry']}/ros/payload:1.0, running, restart always: "
        "it runs the payload's image)"
    ) in run.output
    assert "ros_payload (compose project rosapp, " in run.output
    for host in ("robot2", "robot3"):
        assert f"[{host}] payload: taking over what runs the payload another way" in run.output
        assert running_payloads(lab, host) == [f"{PROJECT}-payload-1"]
        assert foreign_state(lab, host) == ("exited", "no")
        taken = lab.record(host)["taken_over"]
        assert [(c["name"], c["restart"], c["running"]) for c in taken] == [("ros_payload", "always", True)]
    assert lab.record("robot2")["taken_over"][0]["project"] == "rosapp"
    assert lab.record("robot2")["taken_over"][0]["why"] == "payload_replaces names its compose project"
    assert (
        "[robot3] payload: stopped ros_payload (" + lab.state["registry"] + "/ros/payload:1.0): "
        "it runs the payload's image"
    ) in run.output  # what payloadctl stopped, from its result
    # A rerun changes nothing on robot2; on robot3 a copy started by hand
    # since then (the project already running there) is taken over too.
    lab.ok(
        "robot3",
        f"docker run -d --restart unless-stopped --name ros_payload_copy {lab.state['registry']}/ros/payload:1.0",
    )
    rerun = lab.provision(*limits("robot2", "robot3"), fleet=good, label="(takeover rerun, robot3 copy)")
    assert rerun.returncode == 0 and rerun.changed_hosts == {"robot3"}, rerun.output[-3000:]
    assert "[robot3] payload: taking over what runs the payload another way" in rerun.output
    assert "ros_payload_copy" in rerun.output and "[robot2] payload: taking over" not in rerun.output
    assert [c["name"] for c in lab.record("robot3")["taken_over"]] == ["ros_payload_copy"]
    assert running_payloads(lab, "robot3") == [f"{PROJECT}-payload-1"]

    # Docker restarts: the old containers' restart policy no longer brings them back.
    for host in ("robot2", "robot3"):
        lab.ok(host, "systemctl restart docker")
    for host in ("robot2", "robot3"):
        wait_for(
            lambda: running_payloads(lab, host) == [f"{PROJECT}-payload-1"],
            60,
            f"{host}'s payload after a Docker restart",
        )
        time.sleep(3)
        assert running_payloads(lab, host) == [f"{PROJECT}-payload-1"]

    # A reboot: the unit brings ours back, nothing brings theirs back.
    subprocess.run(["docker", "restart", "-t", "30", f"{lab.prefix}-robot3"], check=True, capture_output=True)
    wait_for(
        lambda: lab.sh("robot3", "systemctl is-active robot-payload")[1].strip() == "active",
        120,
        "robot-payload.service at boot",
    )
    wait_for(
        lambda: lab.payload("robot3")["State"].get("Health", {}).get("Status") == "healthy",
        60,
        "robot3's payload healthy after the reboot",
    )
    assert running_payloads(lab, "robot3") == [f"{PROJECT}-payload-1"]
    assert foreign_state(lab, "robot3") == ("exited", "no")
    assert foreign_state(lab, "robot3", "ros_payload_copy") == ("exited", "no")


HOMEAUTO_COMPOSE = """\
services:
  bridge:
    image: {registry}/ros/payload:1.0
    restart: always
    network_mode: host
"""


def homeauto(lab, host: str) -> tuple[str, str]:
    """State and restart policy of the other project's container."""
    ids = lab.ok(host, "docker ps -aq --filter label=com.docker.compose.project=homeauto").split()
    assert len(ids) == 1, ids
    c = json.loads(lab.ok(host, f"docker inspect {ids[0]}"))[0]
    return c["State"]["Status"], c["HostConfig"]["RestartPolicy"]["Name"]


def test_another_compose_project_of_the_payload_image_is_never_taken_over(lab, fleet):
    """Compose project homeauto runs the payload's own image repository on
    robot1: the first release, an update and a rollback never stop it nor
    touch its restart policy (issue 27, item 2: an update used to)."""
    host = "robot1"
    lab.ok(
        host,
        "systemctl disable --now robot-payload.service && rm -f /etc/systemd/system/robot-payload.service"
        " && systemctl daemon-reload && rm -rf /var/lib/robot-payload",
    )
    lab.ok(host, "docker ps -aq --filter label=com.docker.compose.project=robot-payload | xargs -r docker rm -f")
    lab.ok(
        host,
        "mkdir -p /opt/homeauto && cat > /opt/homeauto/compose.yaml <<'EOF'\n"
        + HOMEAUTO_COMPOSE.format(registry=lab.state["registry"])
        + "EOF\n"
        "docker compose -p homeauto -f /opt/homeauto/compose.yaml up -d",
    )
    try:
        assert homeauto(lab, host) == ("running", "always")
        for label, tag in (("first release", "1.0"), ("update", "1.1")):
            run = lab.provision(
                *limits(host),
                fleet=fleet(f'    payload_image: "@registry@/ros/payload:{tag}"\n'),
                label=f"({host} {label} beside homeauto)",
            )
            assert run.returncode == 0, run.output[-4000:]
            assert "taking over" not in run.output and "homeauto" not in run.output, run.output[-3000:]
            assert homeauto(lab, host) == ("running", "always"), label
            assert lab.version(host) == tag and lab.record(host)["state"] == "active"
        back = lab.provision(*limits(host), script="rollback.py", label=f"({host} rollback beside homeauto)")
        assert back.returncode == 0, back.output[-4000:]
        assert lab.version(host) == "1.0" and homeauto(lab, host) == ("running", "always")
    finally:
        lab.ok(host, "docker compose -p homeauto -f /opt/homeauto/compose.yaml down && rm -rf /opt/homeauto")
    run = lab.provision(*limits(host), label=f"({host} back on the lab fleet)")
    assert run.returncode == 0, run.output[-3000:]
