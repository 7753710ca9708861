"""The apply lock's token (payloadctl hold): the pull agent holds the
robot's apply lock for a whole converge run, and the payload's apply inside
that run joins it instead of waiting for itself; everything else (a push
deploy, the boot's start) meets the held lock as it meets any holder.  The
zip application runs as a process against the stand-ins for docker and
systemctl, as in tests/integration/payloadrobot.py."""

from __future__ import annotations

import contextlib
import json
import os
import re
import signal
import socket
import subprocess
import sys
import time

from roles.payload.payloadctl import lock as apply_lock
from tests.integration.payloadrobot import switching, wait_until
from tests.unit.harness import ROBOT, converged, plan

# COMMAND for `payloadctl hold`: an apply (and a rollback) as part of the
# holder's run, the token read from the file hold names in the environment.
JOINED = """
import json, os, subprocess, sys
helper, request, root = sys.argv[1:4]
token = open(os.environ["PAYLOADCTL_LOCK_TOKEN_FILE"]).read().strip()
data = json.load(open(request))
data["run"]["lock_token"] = token
open(request, "w").write(json.dumps(data))
codes = [subprocess.run([sys.executable, helper, "apply", request, "--run-id", "joined-1"]).returncode]
if len(sys.argv) > 4:
    codes.append(subprocess.run([sys.executable, helper, "rollback", "--dir", root, "--run-id", "joined-2",
                                 "--lock-token-file", os.environ["PAYLOADCTL_LOCK_TOKEN_FILE"]]).returncode)
print(json.dumps(codes))
"""


def hold(robot, tmp_path, *command, timeout=30, wait=True):
    args = [
        sys.executable,
        robot.helper,
        "hold",
        "--dir",
        str(robot.root),
        "--token-file",
        str(tmp_path / "token"),
        "--by",
        "robot-pull agent",
        "--",
        *command,
    ]
    if not wait:
        return subprocess.Popen(args, env=robot.env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    return subprocess.run(args, env=robot.env(), capture_output=True, text=True, timeout=timeout)


def result_of(robot, run_id):
    return json.loads(robot.result(run_id).stdout)


def test_hold_runs_its_command_with_a_private_token_and_lets_go(robot, tmp_path):
    probe = (
        "import os, stat, json; p = os.environ['PAYLOADCTL_LOCK_TOKEN_FILE']; "
        "print(json.dumps([p, oct(stat.S_IMODE(os.stat(p).st_mode)), open(p).read().strip()])); "
        "raise SystemExit(7)"
    )
    proc = hold(robot, tmp_path, sys.executable, "-c", probe)
    path, mode, token = json.loads(proc.stdout)
    assert proc.returncode == 7  # the command's own exit status
    assert path == str(tmp_path / "token") and mode == "0o600" and re.fullmatch(r"[0-9a-f]{64}", token)
    assert not (tmp_path / "token").exists()
    lock = apply_lock.Lock(str(robot.root))
    assert lock.holder() is None and not os.path.exists(lock.owner_path)  # released, note gone


def test_an_apply_and_a_rollback_carrying_the_token_join_the_holders_run(robot, tmp_path):
    robot.image("reg/ros/payload:1.1")
    request = robot.spec("reg/ros/payload:1.1", "joined-1", apply_lock_timeout=1)
    proc = hold(robot, tmp_path, sys.executable, "-c", JOINED, robot.helper, request, str(robot.root), "rollback")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert json.loads(proc.stdout.strip().splitlines()[-1]) == [0, 0]  # neither waited for the lock (1 s, then refused)
    applied, rolled_back = result_of(robot, "joined-1"), result_of(robot, "joined-2")
    assert applied["outcome"] == "applied"
    assert rolled_back["outcome"] == "applied" and rolled_back["action"] == "rollback"
    assert robot.pointers()[0] == "r1"  # updated to 1.1, then rolled back to 1.0
    assert "waiting" not in proc.stderr and "lock_token" not in json.dumps([applied, rolled_back])


def test_a_push_deploy_and_a_wrong_token_wait_for_the_agent_as_for_any_holder(robot, tmp_path):
    robot.image("reg/ros/payload:1.1")
    agent = hold(robot, tmp_path, sys.executable, "-c", "import time; time.sleep(30)", wait=False)
    try:
        wait_until(lambda: (tmp_path / "token").exists(), "the agent to hold the lock")
        pushed = robot.apply("reg/ros/payload:1.1", run_id="push-1", apply_lock_timeout=1)
        wrong = json.loads(open(robot.spec("reg/ros/payload:1.1", "push-2", apply_lock_timeout=1)).read())
        wrong["run"]["lock_token"] = "0" * 64
        path = robot.root.parent / "wrong.json"
        path.write_text(json.dumps(wrong))
        robot.payloadctl("apply", str(path), "--run-id", "push-2")
        guessed = robot.result("push-2")
    finally:
        agent.send_signal(signal.SIGTERM)
        agent.wait(timeout=30)
    for result in (pushed, guessed):
        line = result.stderr.strip()
        assert result.returncode == 1
        assert line.startswith(f"payload: another deploy is running on {socket.gethostname()} since 20"), line
        assert line.endswith("(by robot-pull agent); gave up after 1 s (payload_apply_lock_timeout)"), line
    assert json.loads(pushed.stdout)["outcome"] == "refused"
    assert robot.pointers() == ("r1", None) and "started" not in robot.state()
    assert not (tmp_path / "token").exists()  # hold stopped by a signal still cleans up
    assert apply_lock.Lock(str(robot.root)).holder() is None


def test_the_boot_start_meets_the_agents_lock_as_any_holders(robot, tmp_path):
    """At boot the unit starts current as it is while the agent holds the
    lock; the agent's own apply (joined) undoes the unverified switch."""
    robot.image("reg/ros/payload:1.1")
    switching(robot, "r2", "reg/ros/payload:1.1", "apply", "r1", None)
    robot.releases.point("previous", "r1")
    robot.releases.point("current", "r2")
    agent = hold(robot, tmp_path, sys.executable, "-c", "import time; time.sleep(30)", wait=False)
    try:
        wait_until(lambda: (tmp_path / "token").exists(), "the agent to hold the lock")
        boot = robot.payloadctl("start", "--dir", str(robot.root), "--name", "robot-payload")
    finally:
        agent.send_signal(signal.SIGTERM)
        agent.wait(timeout=30)
    assert boot.returncode == 0, boot.stderr
    assert "another deploy is running" in boot.stderr and boot.stderr.rstrip().endswith("starting current as it is")
    assert robot.pointers()[0] == "r2" and robot.releases.record("r2")["state"] == "switching"


def test_a_joined_apply_holds_the_lock_itself_when_the_agent_goes_away(robot, tmp_path):
    """The agent stopped mid-run (its hold killed): the apply it started
    goes on, so no other deploy may start until that apply is done."""
    robot.image("reg/ros/payload:1.1")
    request = robot.spec("reg/ros/payload:1.1", "joined-1")
    env = robot.env(FAKE_COMPOSE_SLEEP="4")
    agent = subprocess.Popen(
        [
            sys.executable,
            robot.helper,
            "hold",
            "--dir",
            str(robot.root),
            "--token-file",
            str(tmp_path / "token"),
            "--",
            sys.executable,
            "-c",
            JOINED,
            robot.helper,
            request,
            str(robot.root),
        ],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    try:
        wait_until(lambda: "compose_up" in robot.state(), "the joined apply's compose up", seconds=20)
        lock = apply_lock.Lock(str(robot.root))
        os.kill(agent.pid, signal.SIGKILL)  # hold only: its command (and the apply) go on
        agent.wait(timeout=10)
        wait_until(lambda: (lock.holder() or {}).get("action") == "apply", "the joined apply to hold the lock")
        held = lock.holder()
        assert held["run_id"] == "joined-1" and not held.get("foreign")
        other = robot.apply("reg/ros/payload:1.0", run_id="push-3", apply_lock_timeout=1)
        assert other.returncode == 1 and "gave up after 1 s" in other.stderr
        finished = robot.root / "runs" / "joined-1" / "result.json"
        wait_until(finished.exists, "the joined apply to finish", seconds=30)
        wait_until(lambda: lock.holder() is None, "the joined apply to let go")
    finally:
        with contextlib.suppress(ProcessLookupError):  # the group is gone once the apply it left ran out
            os.killpg(agent.pid, signal.SIGKILL)
    assert result_of(robot, "joined-1")["outcome"] == "applied"


def test_hold_says_so_and_exits_75_when_the_lock_stays_busy(robot, tmp_path):
    robot.release("r1", "reg/ros/payload:1.0", spec={"apply_lock_timeout": 1})  # hold waits as the release says
    held = apply_lock.Lock(str(robot.root), 0, {"by": "ops@laptop (pyinfra)", "action": "apply"}).acquire()
    try:
        started = time.monotonic()
        proc = hold(robot, tmp_path, "true")
    finally:
        held.release()
    assert proc.returncode == 75 and not (tmp_path / "token").exists()
    assert time.monotonic() - started < 60  # its 1 s, not a default wait (a loaded machine takes seconds to start it)
    assert "another deploy is running" in proc.stderr and proc.stderr.rstrip().endswith(
        "(by ops@laptop (pyinfra)); gave up after 1 s (payload_apply_lock_timeout)"
    )


# --- the deploy's side: payload_lock_token ----------------------------------------

TOKEN = "ab" * 32


def test_the_token_reaches_payloadctl_on_stdin_only():
    snap = converged("robots", ROBOT, "debian-13")
    data = {**ROBOT, "payload_image": "reg.example.com/ros/payload:1.1", "payload_lock_token": TOKEN}
    sent = plan({"r1": ("robots", data, snap)})["r1"]
    assert len(sent) == 1 and TOKEN not in str(sent[0])
    assert json.loads(sent[0].stdin)["run"]["lock_token"] == TOKEN
    without = plan({"r1": ("robots", {**data, "payload_lock_token": None}, snap)})["r1"]
    assert "lock_token" not in json.loads(without[0].stdin)["run"]


def test_a_rollback_sends_the_token_into_its_own_private_file():
    snap = converged("robots", ROBOT, "debian-13")
    sent = plan({"r1": ("robots", {**ROBOT, "payload_lock_token": TOKEN}, snap)}, deploy_file="rollback.py")["r1"]
    assert len(sent) == 1 and TOKEN not in str(sent[0]) and sent[0].stdin.strip() == TOKEN
    run_dir = re.search(r"--run-id (\S+)", str(sent[0])).group(1)
    assert f"--lock-token-file /var/lib/robot-payload/runs/{run_dir}/lock-token" in str(sent[0])
    assert "umask 077" in str(sent[0])


def test_a_wrong_token_setting_is_refused_without_being_shown():
    from tests.unit.harness import fleet_problems

    doc = {
        "robots": {
            "hosts": {
                "robot3": {
                    "address": "10.0.0.3",
                    "payload_image": "reg.example.com/a:1",
                    "payload_lock_token": "s3cret-x",
                }
            }
        }
    }
    assert fleet_problems(doc) == [
        "robots.yaml: robot3.payload_lock_token: expected the token payloadctl hold wrote (hex digits); "
        "the value is not shown"
    ]
