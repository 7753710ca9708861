"""Prefetch (robotfleet/pull/robot/prefetch.py): a robot whose release waits
for its maintenance window or its wave puts it in place at once (TUF
targets, tree, venv from a real wheel, images), reports ``prefetched``, and
applies it in its window with nothing downloaded; an interrupted prefetch
is taken up where it stopped; too little disk stops it before anything.

The wake, the TUF repository and the git remote are real (the World of
test_pull_agent.py); Docker is the stand-in CLI of tests/integration/fakebin
(found on PATH, as the agent finds docker on a robot), which keeps the
images it pulled and logs each call.  A real `docker pull` of a release's
images is the end-to-end layer's."""

from __future__ import annotations

import datetime
import json
import os
import shutil
import subprocess
import zipfile
from pathlib import Path

import pytest

from robotfleet.commands import status
from robotfleet.commands.pull import rollout as pullrollout
from robotfleet.commands.pull import status as pullstatus
from robotfleet.pull.protocol import agent_files, platforms, reports
from robotfleet.pull.robot import agent_state
from tests.integration.pullworld import World
from tests.unit import pullkit
from tests.unit.pullkit import NOW

FAKEBIN = Path(__file__).resolve().parent / "fakebin"
PAYLOAD, ROSCORE = "reg.lan/ros/payload:1", "reg.lan/ros/roscore:2"
IMAGES = {PAYLOAD: "sha256:" + "a" * 64, ROSCORE: "sha256:" + "b" * 64}
BY_DIGEST = [f"reg.lan/ros/payload@{IMAGES[PAYLOAD]}", f"reg.lan/ros/roscore@{IMAGES[ROSCORE]}"]


def window(start_hours: float, end_hours: float) -> str:
    """A daily UTC window from NOW + start to NOW + end hours."""
    at = [(NOW + datetime.timedelta(hours=h)).strftime("%H:%M") for h in (start_hours, end_hours)]
    return f"daily {at[0]}-{at[1]} UTC"


OUTSIDE, INSIDE = window(2, 3), window(-1, 1)


def wheel(base: Path) -> Path:
    """A real (tiny) wheel, installable by pip with no index."""
    path = base / "pf_probe-1.0-py3-none-any.whl"
    files = {
        "pf_probe/__init__.py": "ANSWER = 42\n",
        "pf_probe-1.0.dist-info/METADATA": "Metadata-Version: 2.1\nName: pf-probe\nVersion: 1.0\n",
        "pf_probe-1.0.dist-info/WHEEL": "Wheel-Version: 1.0\nGenerator: test\nRoot-Is-Purelib: true\n"
        "Tag: py3-none-any\n",
    }
    record = "".join(f"{name},,\n" for name in files) + "pf_probe-1.0.dist-info/RECORD,,\n"
    with zipfile.ZipFile(path, "w") as archive:
        for name, text in {**files, "pf_probe-1.0.dist-info/RECORD": record}.items():
            archive.writestr(name, text)
    return path


class Robot(World):
    """The World, with releases that carry images and a wheel, and a docker CLI."""

    def __init__(self, base: Path, monkeypatch):
        super().__init__(base)
        self.docker_state = base / "docker.json"
        self.docker_state.write_text(
            json.dumps({"images": {ref: {"id": "sha256:" + ref[-64:], "pull": "ok"} for ref in BY_DIGEST}})
        )
        monkeypatch.setenv("FAKE_STATE", str(self.docker_state))
        monkeypatch.setenv("PATH", f"{FAKEBIN}{os.pathsep}{os.environ['PATH']}")
        self.windows(OUTSIDE)

    def windows(self, *given: str, **more) -> None:
        self.config = agent_files.Config(**{**self.config.__dict__, "windows": tuple(given), **more})

    def release(self, version: int, robots=("robot1", "robot2"), archive=None, canary="1", pause=0, wheels=True):
        made = wheel(self.base)
        target = f"wheels/{made.name}"
        carried = {target: made} if wheels else {}
        built, built_archive = self.record(
            version, robots, canary, {"robot1": dict(IMAGES)}, {platforms.platform_key(): list(carried)}, pause
        )
        self.fleet.repository.publish(
            built,
            {built.code: archive or built_archive, **carried},
            self.fleet.keys.signer("online"),
            self.fleet.expiry,
            NOW,
        )
        self.push()
        return built

    def docker_log(self) -> list[str]:
        return json.loads(self.docker_state.read_text()).get("log", [])

    def set_pull(self, ref: str, mode: str) -> None:
        state = json.loads(self.docker_state.read_text())
        state["images"][ref]["pull"] = mode
        self.docker_state.write_text(json.dumps(state))

    def placed(self) -> dict[str, int]:
        """What the release put in place, by inode: a file or directory
        downloaded or made again would be a new one."""
        found = {}
        for kind in ("targets", "code", "venvs"):
            for path in sorted((self.state / kind).rglob("*")):
                if not path.is_symlink() and (path.is_file() or path.parent == self.state / kind):
                    found[str(path.relative_to(self.state))] = path.stat().st_ino
        return found


@pytest.fixture
def robot(tmp_path, monkeypatch):
    return Robot(tmp_path, monkeypatch)


@pytest.fixture
def converges(tmp_path, monkeypatch):
    """Where the release's (stub) converge notes each action it is asked, and the switch when it runs."""
    path = tmp_path / "converges.log"
    monkeypatch.setenv("STUB_LOG", str(path))
    return path


def test_outside_its_window_a_release_is_prefetched_and_in_its_window_only_switched(robot, converges):
    record = robot.release(1)
    report, outcome, sent = robot.wake()
    assert outcome.result == "prefetched" and sent == "report sent"
    assert outcome.reason.startswith(
        "release 1 prefetched (code, 1 wheel(s), 2 image(s), its switch prepared); outside the maintenance window; "
        "next at "
    )
    assert converges.read_text() == "prepare\n"  # the release's converge planned it, once
    assert robot.pushed_report()["result"] == "prefetched"
    # everything in place, nothing switched
    code = robot.state / "code" / record.tree_sha256
    assert (code / "inventories" / "robots.yaml").is_file() and not (robot.state / "code" / "current").exists()
    [venv] = [p for p in (robot.state / "venvs").iterdir() if p.name != "stub"]
    assert (venv / "bin" / "python").exists() and os.readlink(robot.state / "venv") == "venvs/stub"
    assert [line for line in robot.docker_log() if " pull " in line] == [f"docker pull -q {ref}" for ref in BY_DIGEST]
    # only images asked for and pulled: no container touched, no converge run (nor its apply lock)
    assert all(line.startswith(("docker image inspect ", "docker pull ")) for line in robot.docker_log())
    assert not (robot.state / "last-run.log").exists()
    state = agent_state.load_state(robot.state)
    assert state.get("applied") is None and state.get("attempted") is None
    placed, calls = robot.placed(), len(robot.docker_log())
    assert any(name.startswith("targets/wheels/") for name in placed) and f"code/{record.tree_sha256}" in placed

    # a later check outside the window: already prefetched, nothing asked of Docker, nothing new to report
    _, again, sent = robot.wake()
    assert (again.result, sent) == ("prefetched", "report unchanged") and len(robot.docker_log()) == calls

    # the window opens: the switch, with nothing downloaded, unpacked, made or pulled
    robot.windows(INSIDE)
    _, applied, _ = robot.wake()
    assert applied.result == "applied", applied.reason
    assert robot.placed() == placed and robot.docker_log()[calls:] == []
    assert os.path.realpath(robot.state / "venv") == str(venv)
    assert os.path.realpath(robot.state / "code" / "current") == str(code)
    # the prepared switch first, then the release's whole converge (which finds it in place)
    assert converges.read_text() == "prepare\nswitch\nrun\n"


def test_a_release_that_changes_more_than_what_runs_is_converged_whole_in_its_window(robot, converges, monkeypatch):
    monkeypatch.setenv("STUB_PREPARE", "it changes more than what runs: Docker | Write /etc/docker/daemon.json")
    robot.release(1)
    _, outcome, _ = robot.wake()
    assert outcome.result == "prefetched"
    assert "2 image(s), its window runs the whole converge: it changes more than what runs: Docker | " in outcome.reason
    _, again, _ = robot.wake()  # planned once a release
    assert again.result == "prefetched" and converges.read_text() == "prepare\n"
    robot.windows(INSIDE)
    _, applied, _ = robot.wake()
    assert applied.result == "applied" and converges.read_text() == "prepare\nrun\n"


def test_a_prepared_switch_that_rolls_back_is_the_window_s_outcome(robot, converges, monkeypatch):
    robot.release(1)
    robot.wake()
    robot.windows(INSIDE)
    monkeypatch.setenv("STUB_SWITCH", "rolled-back")
    _, outcome, _ = robot.wake()
    assert (outcome.result, outcome.reason) == ("rolled-back", "release 1: payload: release r-prepared rolled-back")
    assert converges.read_text() == "prepare\nswitch\n"  # not tried again whole in the same window
    assert agent_state.load_state(robot.state)["attempted"]["result"] == "rolled-back"


def test_a_prepared_switch_that_gives_way_leaves_the_window_to_the_whole_converge(robot, converges, monkeypatch):
    """The prepared release gone (a push deploy since, say): payloadctl refuses, nothing switched."""
    robot.release(1)
    robot.wake()
    robot.windows(INSIDE)
    monkeypatch.setenv("STUB_SWITCH", "refused")
    _, outcome, _ = robot.wake()
    assert outcome.result == "applied" and converges.read_text() == "prepare\nswitch\nrun\n"


def test_a_release_whose_wave_opens_later_is_prefetched(robot):
    robot.windows()
    robots = ["robot1", "robot2"]
    waves = pullkit.module("protocol.waves")
    plan = waves.parse_plan({"canary": "1", "waves": ["100%"], "pause": 600, "max_failed": "0"})
    version = next(v for v in range(1, 50) if waves.wave_of("robot1", robots, v, plan) == 1)
    robot.release(version, robots=robots, pause=600, wheels=False)
    _, outcome, _ = robot.wake()
    assert (outcome.result, outcome.wave) == ("prefetched", 1) and "waiting for wave 1 (opens at " in outcome.reason


def test_an_interrupted_prefetch_takes_up_where_it_stopped(robot):
    robot.release(1)
    robot.set_pull(BY_DIGEST[1], "down")  # the network goes away after the first image
    _, outcome, sent = robot.wake()
    assert outcome.result == "waiting" and sent == "report sent"
    assert outcome.reason.startswith(
        f"release 1 not prefetched yet: docker pull {BY_DIGEST[1]}: Error response from daemon: "
    )
    assert outcome.reason.endswith(
        " dial tcp: connection refused; outside the maintenance window; next at "
        f"{outcome.reason.rsplit('next at ', 1)[1]}"
    )
    assert agent_state.load_state(robot.state).get("attempted") is None  # not a failed release
    placed, calls = robot.placed(), len(robot.docker_log())
    assert any(name.startswith("targets/wheels/") for name in placed)

    robot.set_pull(BY_DIGEST[1], "ok")
    _, outcome, _ = robot.wake()
    assert outcome.result == "prefetched"
    assert robot.placed() == placed  # the targets, tree and venv of the first try, not downloaded or made again
    assert [line for line in robot.docker_log()[calls:] if " pull " in line] == [f"docker pull -q {BY_DIGEST[1]}"]


@pytest.fixture
def own_disk(robot, tmp_path):
    """The robot's state directory on a file system of its own (a 256 MB
    tmpfs), so that what it has free is what this test leaves there: on the
    test command's shared disk the labs beside it take and give back
    hundreds of MB between the test's reading and the agent's."""
    disk = tmp_path / "disk"
    disk.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256m", "tmpfs", str(disk)], capture_output=True)
    if mounted.returncode:
        pytest.skip(f"a tmpfs of a known size needs root: {mounted.stderr.decode().strip()}")
    try:
        shutil.copytree(robot.state, disk / "state", symlinks=True)
        robot.state = disk / "state"
        robot.config = agent_files.Config(**{**robot.config.__dict__, "state_dir": str(robot.state)})
        yield robot
    finally:
        subprocess.run(["umount", "-l", str(disk)], check=True)


def test_too_little_disk_for_the_release_prefetches_nothing_and_says_why(own_disk):
    robot = own_disk
    big = robot.base / "big.tar.gz"
    with open(big, "wb") as handle:
        handle.truncate(64 << 20)  # 64 MB the robot would download (and unpack)
    robot.release(1, archive=big)
    needed = -(-3 * (big.stat().st_size + (robot.base / "pf_probe-1.0-py3-none-any.whl").stat().st_size) >> 20)
    free = shutil.disk_usage(robot.state).free >> 20
    assert needed > 96 < free  # the check can start (free - 96 >= 0), the release cannot be taken
    robot.windows(OUTSIDE, min_free_mb=free - 96)  # enough for the check to start, not to take 3 x 64 MB
    before = robot.placed()
    _, outcome, _ = robot.wake()
    assert outcome.result == "waiting"
    assert outcome.reason.startswith(f"release 1 not prefetched yet: it needs about {needed} MB, ")
    assert f"MB are free on {robot.state}'s file system (pull_min_free_mb: {free - 96}); outside the " in outcome.reason
    assert robot.placed() == before and robot.docker_log() == []


def test_a_robot_without_docker_yet_prefetches_the_rest(robot, tmp_path, monkeypatch):
    """A first-boot robot: the release's converge installs Docker, and pulls its images then."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    os.symlink(shutil.which("git"), bin_dir / "git")
    monkeypatch.setenv("PATH", str(bin_dir))
    record = robot.release(1, wheels=False)
    _, outcome, _ = robot.wake()
    assert outcome.result == "prefetched"
    assert outcome.reason.startswith("release 1 prefetched (code, 0 wheel(s), no Docker yet: images at the apply); ")
    assert (robot.state / "code" / record.tree_sha256).is_dir() and robot.docker_log() == []


def test_status_and_a_rollout_read_prefetched_as_not_yet_applied_and_not_failed(robot):
    robot.release(1, wheels=False)
    robot.wake()
    report = robot.pushed_report()
    data = {"pull_interval": 60, "pull_jitter": 5, "pull_stale_after": 3}
    row = pullstatus.row("robot1", report, data, NOW, "url")
    assert row["pull"] == "prefetched 1" and "error" not in row and row["reachable"] == "pull"
    assert status.exit_code([row]) == 0
    assert {m.name: m.value for m in pullstatus.metrics(row)}["pull_failed"] == 0
    assert pullrollout.outcome(report, 1) is None and not reports.failed_for(report, 1)
