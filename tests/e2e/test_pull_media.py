"""End to end: a pull robot with no network converges from exported media
and refuses tampered or replayed media, and a robot outside its maintenance
window prefetches, then only switches inside it (issue 35 items 6 and 7;
docs/guides/pull.md "Robots with no network: releases on media",
docs/explanations/pull.md "Prefetch before the window"), on the lab's real
Docker engine.

One robot of the session's lab (robot3), its own pull agent and release
keys on the lab's git server, its timer at an hour (every check here is
started by the test).  The module starts from nothing of pull mode on that
robot or the fleet remote (whatever an earlier module left there is
removed), and removes what it made at its end, so it may run before or
after tests/e2e/test_pull.py.
"""

from __future__ import annotations

import datetime
import json
import re
import subprocess
import time
from pathlib import Path

import pytest

from tests.e2e.conftest import phase
from tests.e2e.pullmode import Pull, by_digest, clear_remote, ssh_error

pytestmark = pytest.mark.e2e

ROBOT = "robot3"
MEDIUM = "/mnt/fleet-media"
# Every check is the test's own (the timer's first check after install aside).
QUIET = {
    "payload_health_timeout": 20,
    "payload_stable_seconds": 2,
    "pull_interval": 3600,
    "pull_jitter": 0,
    "pull_media_dir": MEDIUM,
}
RESET = "systemctl disable --now robot-pull.timer; rm -rf /etc/robot-pull /var/lib/robot-pull " + MEDIUM


class Media(Pull):
    def fleet(self, tag: str, robots=(ROBOT,), repository: str = "ros/payload", **more) -> str:
        text = self.pullfleet.fleet_text(self.op.lab, payload_tag="1.0", robots=list(robots), **{**QUIET, **more})
        fleet = json.loads(text.split("\n", 1)[1])
        fleet["all"]["vars"]["payload_image"] = self.pullfleet.pinned(self.op.lab, repository, tag)
        return text.split("\n", 1)[0] + "\n" + json.dumps(fleet, indent=1) + "\n"

    def check(self) -> None:
        self.trigger([ROBOT])

    def report(self) -> dict:
        return self.reports()[ROBOT]

    def medium_report(self) -> dict:
        return json.loads(self.lab.ok(ROBOT, f"cat {MEDIUM}/reports/{ROBOT}.json"))

    def export(self, directory: Path) -> dict:
        """robotfleet export DIR as the operator runs it (the registry read by
        the robots' name for it); media.json as exported."""
        from tests.lab.registryproxy import RegistryProxy

        proxy = RegistryProxy(self.op.lab["registry"], self.op.lab["registry_local"])
        try:
            done = self.op.robotfleet(
                "export",
                str(directory),
                "--checkout",
                str(self.op.repo),
                "--keys",
                str(self.op.keys),
                env=self.op.env(**proxy.env()),
            )
        finally:
            proxy.close()
        assert "export" in done.stdout + done.stderr, done.stdout + done.stderr
        found = [p for p in directory.rglob("*media.json") if p.is_file()]
        assert len(found) == 1, found
        return json.loads(found[0].read_text())

    def insert(self, directory: Path) -> None:
        """The medium mounted on the robot: DIR copied to a scratch directory
        and moved into place (a check never reads half a copy)."""
        container = f"{self.lab.prefix}-{ROBOT}"
        self.lab.ok(ROBOT, f"rm -rf {MEDIUM} {MEDIUM}.new")
        subprocess.run(["docker", "cp", str(directory), f"{container}:{MEDIUM}.new"], check=True, capture_output=True)
        self.lab.ok(ROBOT, f"chown -R root:root {MEDIUM}.new && mv {MEDIUM}.new {MEDIUM}")

    def network(self, connected: bool) -> None:
        """The robot on the lab network (the git server, the registry) or cut from it, still running."""
        from tests.lab.engine import client

        dc = client()
        network, container = dc.networks.get(f"{self.lab.prefix}-net"), dc.containers.get(f"{self.lab.prefix}-{ROBOT}")
        container.reload()
        attached = f"{self.lab.prefix}-net" in container.attrs["NetworkSettings"]["Networks"]
        if connected and not attached:
            network.connect(container)
        elif not connected and attached:
            network.disconnect(container)

    def pinned(self, repository: str, tag: str) -> str:
        return self.pullfleet.pinned(self.op.lab, repository, tag)


def forget_images(world, images) -> None:
    """The robot without these images (the lab's other modules ran some of
    them on it): the tests need images it does not have yet."""
    for repository, tag in images:
        ref = by_digest(world.pinned(repository, tag))
        world.lab.sh(ROBOT, f"id=$(docker image inspect -f '{{{{.Id}}}}' {ref}) && docker image rm -f $id")
        assert world.lab.sh(ROBOT, f"docker image inspect {ref}")[0] != 0, f"{ROBOT} still has {ref}"


@pytest.fixture(scope="module")
def world(lab, tmp_path_factory):
    started = time.monotonic()
    world = Media(lab, tmp_path_factory.mktemp("pull-media"))
    op = world.op
    lab.ok(ROBOT, RESET)
    clear_remote(world)
    op.setup()
    op.publish(world.fleet("1.0"), "release 1", "--pause", "0")
    world.release1 = world.attacks.checkout()
    world.old_timestamp = (world.attacks.work / "metadata" / "timestamp.json").read_bytes()
    run = lab.provision(
        f"--limit={ROBOT}",
        fleet=op.repo / world.pullfleet.FLEET,
        label="(pull agent, media)",
        env={"ROBOTFLEET_KEYS": str(op.keys), "ROBOTFLEET_RELEASES_CLONE": str(op.base / "releases")},
    )
    assert run.returncode == 0, run.output[-4000:]
    op.register_robots([ROBOT])
    world.check()
    report = world.report()
    assert report["result"] in ("applied", "up-to-date") and report["applied"]["version"] == 1, report
    forget_images(world, [("ros/payload", "1.1"), ("ros/driver", "1.0"), ("ros/driver", "1.1")])
    phase("pull media: release 1 on the robot by push, its agent enrolled", started)
    yield world
    world.network(True)
    lab.sh(ROBOT, RESET)
    clear_remote(world)


def test_a_robot_with_its_network_cut_converges_from_exported_media_and_refuses_tampered_media(world, lab, tmp_path):
    started = time.monotonic()
    world.network(False)
    try:
        assert lab.sh(ROBOT, f"getent hosts {lab.state['services_host']}")[0] != 0  # cut: no name, no route
        world.op.publish(world.fleet("1.1"), "release 2: payload 1.1", "--no-wheels", "--pause", "0")
        ref = world.pinned("ros/payload", "1.1")
        index = world.export(tmp_path / "media-2")
        assert index["version"] == 2, index
        entry = index["images"]["x86_64"][ref]
        assert entry["digest"] == ref.split("@", 1)[1], entry
        assert lab.sh(ROBOT, f"docker image inspect {by_digest(ref)}")[0] != 0  # not on the robot before
        world.insert(tmp_path / "media-2")
        world.check()
        report = world.medium_report()  # the remote is out of reach: the report is on the medium
        assert report["result"] == "applied" and report["applied"]["version"] == 2, report
        assert lab.version(ROBOT) == "1.1"
        payload = lab.payload(ROBOT)
        assert payload["Image"] == entry["image"], (payload["Image"], entry)  # the image id the release binds
        # Docker's containerd image store keeps the archive's registry digest; the classic one (the lab's
        # Docker 26, overlay2) only the id: the agent tags the id it checked by the digest's hex
        repository, digest = by_digest(ref).split("@")
        containerd = lab.ok(ROBOT, "docker info -f '{{.Driver}}'").strip() != "overlay2"
        assert payload["Config"]["Image"] == (
            by_digest(ref) if containerd else f"{repository}:media-sha256-{digest[7:]}"
        ), payload["Config"]
        loaded = json.loads(lab.ok(ROBOT, f"docker image inspect {payload['Config']['Image']}"))[0]
        assert loaded["Id"] == entry["image"], loaded["Id"]
        phase("pull media: release 2 applied from the medium, network cut", started)

        # an image the robot does not have yet (one it has by the digest is not loaded again: its archive unread)
        before, ref = lab.record(ROBOT), world.pinned("ros/driver", "1.1")
        assert lab.sh(ROBOT, f"docker image inspect {by_digest(ref)}")[0] != 0
        world.op.publish(
            world.fleet("1.1", repository="ros/driver"), "release 3: ros/driver 1.1", "--no-wheels", "--pause", "0"
        )
        index = world.export(tmp_path / "media-3")
        assert ref in index["images"]["x86_64"], index
        archives = sorted((tmp_path / "media-3").rglob("*.tar"))
        assert archives, "no image archive exported"
        for archive in archives:  # one byte flipped in the middle of each
            with archive.open("r+b") as handle:
                handle.seek(archive.stat().st_size // 2)
                byte = handle.read(1)
                handle.seek(-1, 1)
                handle.write(bytes([byte[0] ^ 0xFF]))
        world.insert(tmp_path / "media-3")
        world.check()
        report = world.medium_report()
        assert (report["result"], report.get("refusal")) == ("refused", "tampered"), report
        assert lab.version(ROBOT) == "1.1" and lab.record(ROBOT) == before
        assert lab.sh(ROBOT, f"docker image inspect {by_digest(ref)}")[0] != 0  # refused before docker load

        # the same release's good media, with a timestamp older than the robot trusts (release 1's)
        replayed = tmp_path / "media-3-old-timestamp"
        index = world.export(replayed)
        (replayed / "metadata" / "timestamp.json").write_bytes(world.old_timestamp)
        world.insert(replayed)
        world.check()
        report = world.medium_report()
        assert (report["result"], report.get("refusal")) == ("refused", "rollback"), report
        assert lab.version(ROBOT) == "1.1" and lab.record(ROBOT) == before
        phase("pull media: tampered and replayed media refused", started)
    finally:
        lab.sh(ROBOT, f"rm -rf {MEDIUM}")
        world.network(True)
    assert ssh_error(lab, ROBOT) is None  # its SSH port published again


def window_from(start: datetime.datetime, minutes: int = 30) -> str:
    end = start + datetime.timedelta(minutes=minutes)
    return f"daily {start:%H:%M}-{end:%H:%M} UTC"


class PullsSeen:
    """The images the robot's Docker pulls while this watch runs, seen as
    they happen: a live `docker events` subscription (a transient unit on the
    robot), filtered by the daemon.  Not `docker events --since` read
    afterwards: the daemon keeps only its last 256 events for that, and each
    health check of each running container adds three (an exec's create,
    start and die, every 2 s for the lab's payload), so on a robot the
    modules before left running a few containers a pull drops out of that
    history within a minute (a prefetch check outlasts that: once in the
    full sequence its pull was no longer there to read)."""

    UNIT = "robot-lab-pulls"

    def __init__(self, lab):
        self.lab, self.out = lab, f"/run/{self.UNIT}.out"
        lab.sh(ROBOT, f"systemctl stop {self.UNIT}; systemctl reset-failed {self.UNIT}; rm -f {self.out}")
        # --since: what the daemon sent before the subscription took hold is replayed, nothing is missed
        lab.ok(
            ROBOT,
            f"systemd-run -q --unit {self.UNIT} -p StandardOutput=file:{self.out} docker events "
            "--since $(date +%s) --filter type=image --filter event=pull --format '{{.Actor.ID}}'",
        )
        lab.ok(ROBOT, f"systemctl is-active -q {self.UNIT}")

    def stop(self) -> list[str]:
        self.lab.ok(ROBOT, f"systemctl stop {self.UNIT}; systemctl reset-failed {self.UNIT} 2>/dev/null; true")
        return self.lab.ok(ROBOT, f"cat {self.out}").split()


PREFETCH_LEAD = 120  # seconds at least to the window: an apply, a publish and a prefetch before it


def test_a_robot_outside_its_window_prefetches_then_switches_inside_it_without_pulling(world, lab):
    started = time.monotonic()
    now = datetime.datetime.now(datetime.timezone.utc)
    opens = (now + datetime.timedelta(seconds=PREFETCH_LEAD + 59)).replace(second=0, microsecond=0)
    window = window_from(opens)
    # The window reaches the robot's agent with a release (applied now: its config had none).
    world.op.publish(
        world.fleet("1.0", pull_windows=[window]), "release: a maintenance window", "--no-wheels", "--pause", "0"
    )
    world.check()
    report = world.report()
    assert report["result"] == "applied", report
    assert window in lab.ok(ROBOT, "cat /etc/robot-pull/agent.json")
    running = lab.version(ROBOT)
    ref = world.pinned("ros/driver", "1.0")
    forget_images(world, [("ros/driver", "1.0")])  # whatever put it there, the prefetch must pull it

    world.op.publish(
        world.fleet("1.0", repository="ros/driver", pull_windows=[window]),
        "release: ros/driver 1.0 in the window",
        "--no-wheels",
        "--pause",
        "0",
    )
    watch = PullsSeen(lab)
    world.check()
    pulled = watch.stop()
    report = world.report()
    version = report["seen"]["version"]
    assert report["result"] == "prefetched", report
    assert (report.get("applied") or {}).get("version") != version, report
    # its plan changes nothing but what runs: the payload's release is written and checked, not switched to
    assert ", its switch prepared)" in report["reason"], report
    prepared = json.loads(lab.ok(ROBOT, "cat /var/lib/robot-payload/last-result.json"))
    assert prepared["outcome"] == "prepared" and prepared["release"] != prepared["target"], prepared
    record = json.loads(lab.ok(ROBOT, f"cat /var/lib/robot-payload/releases/{prepared['target']}/record.json"))
    assert record["state"] == "prepared", record
    assert pulled == [by_digest(ref)], pulled  # pulled by the digest the release names, and only that
    assert lab.sh(ROBOT, f"docker image inspect {by_digest(ref)}")[0] == 0
    assert lab.version(ROBOT) == running  # the old payload still runs
    left = (opens - datetime.datetime.now(datetime.timezone.utc)).total_seconds()
    assert left > 0, f"the window opened {-left:.0f} s before the prefetch was checked (raise PREFETCH_LEAD)"
    phase(f"pull prefetch: release {version} prefetched {left:.0f} s before its window", started)

    time.sleep(left + 2)
    watch = PullsSeen(lab)
    world.check()
    pulled = watch.stop()
    report = world.report()
    assert report["result"] == "applied" and report["applied"]["version"] == version, report
    assert lab.payload(ROBOT)["Config"]["Image"] == by_digest(ref), lab.payload(ROBOT)["Config"]["Image"]
    assert lab.version(ROBOT) == "driver-1.0"
    assert pulled == [], f"the switch pulled {pulled}"
    assert lab.ok(ROBOT, "readlink /var/lib/robot-payload/current").strip() == f"releases/{prepared['target']}"
    # the window's wake switched to the prepared release first, then ran the release's whole converge
    journal = lab.ok(ROBOT, "journalctl -u robot-pull.service -o cat --no-pager")
    took = re.findall(rf"^robot-pull: applied \(release {version}\).*; report sent \[(.*)\]$", journal, re.M)
    names = [part.split(" ")[0] for part in took[-1].split(", ")] if took else None
    assert names == ["fetch", "verify", "decide", "prepare", "switch", "load", "deploy", "status", "report"], journal
    phase(f"pull prefetch: release {version} switched in its window [{took[-1]}]", started)
