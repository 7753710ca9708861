"""End to end over bad links (issue 51, items 2 and 3): the mission's
command, ``pyinfra -y inventories/lab.py deploy.py``, with robots reached
through the lab's fault-injecting proxy on 127.0.0.1 (tests/lab/linkproxy.py).

- A first provisioning at a 300 ms round trip: the session's first run
  reaches robot3 that way when this module is in the session (conftest.py
  ``first_run``), so it costs no provisioning of its own.
- A cut and a freeze in the middle of an update: the cut robot fails naming
  its closed connection, the frozen one within the keepalive bound naming
  its frozen link (the test fleet's ``ssh_keepalive_interval: 2``,
  ``ssh_keepalive_count_max: 3``), the other hosts finish, the run ends;
  each robot finishes its update by itself (payloadctl runs in a unit of
  its own, not in the SSH session), the rerun converges, then 0 changes.
- ``robotfleet status`` with one robot frozen under its open connection
  returns within the same bound, that robot's row naming the frozen link.

Before the keepalives, the freeze and status hung for ever: each command
here has a bound of its own, so the test fails instead.  Robots are left
on the release the first run gave them."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest

from tests.e2e.conftest import ROOT, SLOW_DELAY, SLOW_ROBOT, Run, wait_for
from tests.fixtures import start_pyinfra
from tests.lab.linkproxy import Link, through

pytestmark = pytest.mark.e2e

INTERVAL, COUNT = 2, 3
# Given up after COUNT + 1 silent intervals (OpenSSH's rule), each noticed within an interval; the rest
# is what a loaded two-core machine adds to the end of a run (the other hosts' last steps, the summary).
BOUND = (COUNT + 2) * INTERVAL + 20
KEEPALIVE = f"    ssh_keepalive_interval: {INTERVAL}\n    ssh_keepalive_count_max: {COUNT}\n"
UPDATING = "systemctl list-units --no-legend 'robot-payload-update-*'"


def fleet(lab, tmp_path, tag: str | None = None):
    """The lab's fleet with short keepalives; robot1 and robot2 on ``tag``."""
    replacements = {"    payload_device_wait: 10\n": "    payload_device_wait: 10\n" + KEEPALIVE}
    for robot in ("robot1", "robot2") if tag else ():
        replacements[f"    {robot}:\n"] = f'    {robot}:\n      payload_image: "@registry@/ros/payload:{tag}"\n'
    tmp_path.mkdir(parents=True, exist_ok=True)
    return lab.fleet_with(tmp_path, **replacements)


def port(lab, host: str) -> int:
    return next(h["port"] for h in lab.state["hosts"] if h["name"] == host)


def lines_with(output: str, *texts: str) -> list[str]:
    return [line.strip() for line in output.splitlines() if all(text in line for text in texts)]


def test_a_first_provisioning_at_a_300_ms_round_trip(lab, first_run, slow_link):
    assert SLOW_DELAY * 2 == pytest.approx(0.3)
    assert SLOW_ROBOT in first_run.changed_hosts and SLOW_ROBOT not in first_run.failed_hosts
    assert slow_link.connections >= 1 and slow_link.received > 10_000, "the first run did not go through the link"
    assert lab.version(SLOW_ROBOT) == "1.0"
    print(f"\n[links] first run with {SLOW_ROBOT} at 300 ms RTT: {first_run.seconds:.1f} s wall")


def test_a_cut_and_a_freeze_mid_update_fail_those_robots_in_bound_and_the_rerun_converges(lab, first_run, tmp_path):
    target = "1.1" if lab.version("robot1") != "1.1" else "1.0"
    before = lab.version("robot1")
    updated = fleet(lab, tmp_path / "updated", target)
    with Link(port(lab, "robot1")) as cut, Link(port(lab, "robot2")) as frozen:
        env = dict(
            os.environ,
            ROBOT_LAB_PREFIX=lab.prefix,
            ROBOT_LAB_FLEET=str(updated),
            PYINFRA_PROGRESS="off",
            **through(lab.state, {"robot1": cut, "robot2": frozen}),
        )
        out, err = tmp_path / "stdout", tmp_path / "stderr"
        with open(out, "w") as stdout, open(err, "w") as stderr:
            operator = start_pyinfra(
                "-y",
                "--json",
                "inventories/lab.py",
                "deploy.py",
                env=env,
                stdout=stdout,
                stderr=stderr,
                start_new_session=True,
            )
        frozen_at = None
        try:
            pending = {"robot1": cut.cut, "robot2": frozen.freeze}
            deadline = time.monotonic() + 240
            while pending and time.monotonic() < deadline and operator.poll() is None:
                for robot in list(pending):
                    if "robot-payload-update" in lab.sh(robot, UPDATING)[1]:
                        pending.pop(robot)()
                        frozen_at = time.monotonic() if robot == "robot2" else frozen_at
                time.sleep(0.1)
            assert not pending, f"the update did not start on {sorted(pending)}: {err.read_text()[-3000:]}"
            try:
                operator.wait(BOUND + 60)
            except subprocess.TimeoutExpired:
                raise AssertionError(f"the run still waited {BOUND + 60} s after robot2's link froze") from None
            waited = time.monotonic() - frozen_at
        finally:
            if operator.poll() is None:
                os.killpg(operator.pid, signal.SIGKILL)
                operator.wait()
        said = err.read_text() + out.read_text()
        try:
            results = json.loads(out.read_text())["results"]
        except (ValueError, KeyError):
            results = None
        run = Run(operator.returncode, said, results, waited)
        assert run.returncode == 1, said[-4000:]
        assert run.failed_hosts == {"robot1", "robot2"}, said[-4000:]
        assert len(lines_with(said, "[robot1]", f"connection closed by 127.0.0.1:{cut.port} during a command")) == 1
        frozen_lines = lines_with(said, "[robot2]", f"link frozen: no answer from 127.0.0.1:{frozen.port}")
        assert len(frozen_lines) == 1, said[-4000:]
        assert f"ssh_keepalive_interval: {INTERVAL}, ssh_keepalive_count_max: {COUNT}" in frozen_lines[0]
        assert waited < BOUND, f"the run ended {waited:.1f} s after the freeze"
        print(f"\n[links] the run ended {waited:.1f} s after robot2's link froze")

        # Each robot finishes its update by itself, whatever happened to the link.
        for robot in ("robot1", "robot2"):
            wait_for(lambda r=robot: "robot-payload-update" not in lab.ok(r, UPDATING), 120, f"{robot}'s update")
            assert lab.version(robot) == target, robot
            assert lab.record(robot)["state"] == "active", robot
        frozen.thaw()  # new connections pass: the robots are reached through their links again
        links = through(lab.state, {"robot1": cut, "robot2": frozen})
        rerun = lab.provision(fleet=updated, env=links, label="(after the cut and the freeze)")
        assert rerun.returncode == 0, rerun.output[-4000:]
        if rerun.changed_hosts:
            again = lab.provision(fleet=updated, env=links, label="(converged)")
            assert again.returncode == 0 and again.changed_hosts == set(), again.output[-4000:]
    back = lab.provision("--limit", "robot1,robot2", fleet=fleet(lab, tmp_path / "back", before), label="(back)")
    assert back.returncode == 0, back.output[-4000:]
    assert back.changed_hosts == {"robot1", "robot2"} and {lab.version(r) for r in ("robot1", "robot2")} == {before}


def test_status_with_a_frozen_robot_returns_within_its_bound(lab, first_run, tmp_path):
    """robot2's status command waits on a stopped dockerd (its connection
    open and idle, as a command's may be), then its link freezes."""
    env = dict(os.environ, ROBOT_LAB_PREFIX=lab.prefix, ROBOT_LAB_FLEET=str(fleet(lab, tmp_path)))
    with Link(port(lab, "robot2")) as link:
        env.update(through(lab.state, {"robot2": link}))
        lab.ok("robot2", "kill -STOP $(pidof dockerd)")
        try:
            status = subprocess.Popen(
                [sys.executable, "-m", "robotfleet", "status", "inventories/lab.py", "--json"],
                cwd=ROOT,
                env=env,
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                text=True,
            )
            wait_for(lambda: lab.sh("robot2", "pgrep -x docker")[0] == 0, 60, "status's command on robot2")
            link.freeze()
            frozen_at = time.monotonic()
            try:
                stdout, stderr = status.communicate(timeout=BOUND + 60)
            except subprocess.TimeoutExpired:
                status.kill()
                raise AssertionError("status still waited on robot2's frozen link") from None
            waited = time.monotonic() - frozen_at
        finally:
            lab.ok("robot2", "kill -CONT $(pidof dockerd)")
    rows = {row["host"]: row for row in json.loads(stdout)}
    assert rows["robot2"]["reachable"] is False, stderr[-3000:]
    assert rows["robot2"]["error"].startswith(f"link frozen: no answer from 127.0.0.1:{link.port}"), rows["robot2"]
    assert all(rows[host]["reachable"] for host in rows if host != "robot2"), rows
    assert status.returncode == 3  # a host unreachable, none failed
    assert waited < BOUND, f"status ended {waited:.1f} s after the freeze"
    print(f"\n[links] status ended {waited:.1f} s after robot2's link froze")
