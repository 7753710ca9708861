"""What runs on a robot runs on the robots' own Pythons (issue 51 item 1):
Ubuntu 20.04's 3.8, 22.04's 3.10 and 24.04's 3.12 (tests/pythons.py), not
only the lab robots' 3.13.

payloadctl, the zip application the robots get, through a release's life
against the stand-ins for docker and systemctl (tests/integration/payloadrobot.py:
apply, a broken release rolled back by itself, rollback, the boot's start,
result, status, wait-devices); then, against this machine's real Docker
engine with that Python as /usr/bin/python3 (tests/pythons.py
as_system_python), the host's status command (every role's part,
payloadctl's status among them) and the payload's container reader of the
host snapshot (roles/payload/docker_read.py), each giving what it gives under
this machine's own python3 and what the docker CLI says."""

from __future__ import annotations

import io
import json
import re
import subprocess
import tarfile
import uuid

import pytest

from robotfleet import status_parts
from robotfleet.deploy_roles import roles
from roles.payload import containers
from roles.payload.installed_files import HELPER
from tests import pythons
from tests.integration.payloadrobot import FakeRobot
from tests.unit.harness import merged

ROBOT_PATH = "/usr/sbin:/usr/bin:/sbin:/bin"  # python3 is /usr/bin/python3, as on a robot


@pytest.mark.parametrize("version", pythons.ROBOT_PYTHONS)
def test_payloadctl_runs_a_release_s_life_on_the_robot_s_python(tmp_path, helper, version):
    robot = FakeRobot(tmp_path, helper, pythons.require(version))
    for tag, behaviour in (("1.0", "healthy"), ("1.1", "healthy"), ("bad", "crash")):
        robot.image(f"reg/ros/payload:{tag}", behaviour)
    robot.release("r1", "reg/ros/payload:1.0")
    robot.releases.point("current", "r1")
    robot.running("reg/ros/payload:1.0")

    applied = robot.apply("reg/ros/payload:1.1", run_id="run-2")
    assert applied.returncode == 0 and "is healthy" in applied.stdout, applied.stderr
    new, previous = robot.pointers()
    assert previous == "r1" and robot.releases.record(new)["state"] == "active"
    broken = robot.apply("reg/ros/payload:bad", run_id="run-3")
    assert broken.returncode == 1 and "crash-looping" in broken.stderr, broken.stderr
    assert robot.pointers() == (new, "r1")  # rolled back by itself
    assert robot.result("run-3").returncode == 1
    back = robot.rollback()
    assert back.returncode == 0 and f"rolled back from {new} to r1" in back.stdout, back.stderr
    started = robot.payloadctl("start", "--dir", str(robot.root), "--name", "robot-payload")
    assert started.returncode == 0, started.stderr
    shown = robot.payloadctl("status", "--dir", str(robot.root), "--name", "robot-payload")
    report = json.loads(shown.stdout)
    assert report["current"]["id"] == "r1" and report["previous"]["id"] == new, shown.stderr
    waited = robot.payloadctl("wait-devices", "--timeout", "1", str(tmp_path / "lidar"))
    assert waited.returncode == 1 and waited.stderr.strip().endswith(str(tmp_path / "lidar"))


def _sleeper_image() -> bytes:
    """A container image of this machine's own sleep and the libraries it loads (`docker import`)."""
    libraries = subprocess.run(["ldd", "/bin/sleep"], capture_output=True, text=True, check=True).stdout
    paths = ["/bin/sleep", *re.findall(r"(/\S+) \(0x", libraries)]
    data = io.BytesIO()
    with tarfile.open(fileobj=data, mode="w", dereference=True) as archive:
        for path in paths:
            archive.add(path, arcname=path.lstrip("/"))
    return data.getvalue()


@pytest.fixture(scope="module")
def engine_project():
    """A compose project of one running container on this machine's Docker
    engine, as compose labels it: (project, container id, engine version)."""
    version = subprocess.run(["docker", "version", "-f", "{{.Server.Version}}"], capture_output=True, text=True)
    if version.returncode:
        pythons.skip_or_fail(f"no Docker engine answers here: {version.stderr.strip()[-200:]}")
    project = f"robotfleet-pythons-{uuid.uuid4().hex[:8]}"
    image = f"robotfleet-test/sleep:{project}"
    subprocess.run(["docker", "import", "-", image], input=_sleeper_image(), capture_output=True, check=True)
    started = subprocess.run(
        ["docker", "run", "-d", "--name", f"{project}-payload-1", "--restart", "unless-stopped"]
        + ["--label", f"{containers.LABEL}={project}", "--label", "com.docker.compose.service=payload"]
        + [image, "/bin/sleep", "3600"],
        capture_output=True,
        text=True,
    )
    try:
        assert started.returncode == 0, started.stderr
        yield project, started.stdout.strip(), version.stdout.strip(), image
    finally:
        subprocess.run(["docker", "rm", "-f", f"{project}-payload-1"], capture_output=True)
        subprocess.run(["docker", "rmi", image], capture_output=True)


def _run(argv: list[str]) -> subprocess.CompletedProcess:
    done = subprocess.run(argv, capture_output=True, text=True, timeout=120, env={"PATH": ROBOT_PATH})
    assert done.returncode == 0, done.stderr[-2000:]
    return done


def _host_status(engine_project, tmp_path, helper, prefix: list[str]) -> dict:
    """The host's status row from its one status command, run by sh with ``prefix``."""
    project, _, _, image = engine_project
    tmp_path.mkdir()
    robot = FakeRobot(tmp_path, helper)  # the release store only: the engine is the real one
    robot.save({**robot.state(), "images": {image: {"id": "sha256:" + "e" * 64}}})
    robot.release("r1", image)
    robot.releases.point("current", "r1")
    data = {"payload_dir": str(robot.root), "payload_name": project}
    data["payload_update_lock_path"] = str(robot.root / "update.lock")
    command = status_parts.status_command(roles(), merged("robots", data)).replace(HELPER, helper)
    out = _run([*prefix, "sh", "-c", command]).stdout
    return status_parts.row("robot", roles(), status_parts.sections(out))


@pytest.mark.parametrize("version", pythons.ROBOT_PYTHONS)
def test_the_host_status_on_the_robot_s_python_reads_the_real_engine(engine_project, tmp_path, helper, version):
    python = pythons.require(version)
    _, _, engine, image = engine_project
    row = _host_status(engine_project, tmp_path / version, helper, pythons.as_system_python(python))
    assert row["docker"] == engine and row["release"] == "r1" and row["state"] == "running", row
    assert row["image"] == image and row["health"] == "no check" and row["restarts"] == 0, row
    assert row == _host_status(engine_project, tmp_path / "here", helper, [])  # as under this machine's python3


def _reader_lines(output: str, container: str) -> list[str]:
    """The reader's lines of this project's container (the engine holds others'), its uptime cut off."""
    mine = [line for line in output.splitlines() if line.startswith("c\t") or container in line]
    return [re.sub(r"\tUp .*", "\tUp", line) for line in mine]


@pytest.mark.parametrize("version", pythons.ROBOT_PYTHONS)
def test_the_container_reader_on_the_robot_s_python_says_what_the_docker_cli_says(engine_project, version):
    python = pythons.require(version)
    project, container, _, _ = engine_project
    read = _run([str(python), "-I", "-S", "-c", containers._PROGRAM, project, "foreign"]).stdout
    cli = _run(["sh", "-c", containers.cli(project, True)]).stdout
    assert _reader_lines(read, container) == _reader_lines(cli, container)
    assert _reader_lines(read, container)[0] == "c\trunning\tUp"
