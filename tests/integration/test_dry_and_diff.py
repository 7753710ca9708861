"""pyinfra's real CLI with `--dry` and `--diff` (tests/unit/test_dry_and_diff.py
plans the same in process): @fake hosts answered by the unit harness, in a
fresh interpreter, as an operator runs it."""

import os
import subprocess
import sys

from tests.fixtures import ROOT
from tests.unit.harness import ROBOT
from tests.unit.samples import DAEMON_JSON

CLI = """
import sys
from pyinfra_cli.main import main
from tests.unit.harness import _Recorder, fresh_host
sys.argv = ["pyinfra", *sys.argv[1:]]
with _Recorder({"bad": fresh_host("debian-13"), "good": fresh_host("debian-13")}, {}):
    main()
"""


def dry_run(tmp_path, python: str = sys.executable) -> str:
    """pyinfra --dry over a robot whose docker_users names a missing account and a good one: its
    output, once it exited 1 having named the reason (tests/integration/test_operator_pythons.py: on
    other Pythons)."""
    host = {"payload_image": "reg.example.com/ros/payload:1.0", "fake_delay": 0, "fake_delay_jitter": 0}
    inventory = tmp_path / "fake.py"
    inventory.write_text(
        f"robots = [('@fake/bad', {{**{host!r}, 'docker_users': ['ops', 'ghost']}}), ('@fake/good', {host!r})]\n"
    )
    env = dict(os.environ, PYTHONPATH=str(ROOT), PYINFRA_PROGRESS="off")
    proc = subprocess.run(
        [python, "-c", CLI, "--dry", str(inventory), "deploy.py"],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    output = proc.stdout + proc.stderr
    assert proc.returncode == 1, output[-3000:]
    planning = output.split("--> Preparing operation", 1)[1].split("--> Detected changes", 1)[0]
    reasons = [line.strip() for line in planning.splitlines() if "ghost" in line]
    assert reasons == [
        "[@fake/bad]  docker_users: ghost does not exist on this host; "
        "create the account first (users are never created by this tool)"
    ]
    return output


def test_pyinfra_dry_names_the_reason_and_exits_1(tmp_path):
    dry_run(tmp_path)


DIFF_CLI = """
import sys
from pyinfra_cli.main import main
from tests.unit.harness import _Recorder
from tests.unit.samples import DAEMON_JSON, DRIFTED, drifted_robot
sys.argv = ["pyinfra", *sys.argv[1:]]
with _Recorder({"r1": drifted_robot()}, {"r1": {DAEMON_JSON: DRIFTED}}) as recorder:
    try:
        main()
    finally:
        print("SENT", [str(c) for c in recorder.sent["r1"]])
"""


def test_pyinfra_dry_diff_prints_the_drifted_file(tmp_path):
    inventory = tmp_path / "fake.py"
    host = {**ROBOT, "fake_delay": 0, "fake_delay_jitter": 0}
    inventory.write_text(f"robots = [('@fake/r1', {host!r})]\n")
    env = dict(os.environ, PYTHONPATH=str(ROOT), PYINFRA_PROGRESS="off")
    proc = subprocess.run(
        [sys.executable, "-c", DIFF_CLI, "--dry", "--diff", str(inventory), "deploy.py"],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    output = proc.stdout + proc.stderr
    assert proc.returncode == 0, output[-3000:]
    assert f"[@fake/r1] Will modify {DAEMON_JSON}" in output
    assert '-  "live-restore": false' in output and '+  "live-restore": true,' in output
    # The one thing sent besides the snapshot is the read of that file.
    sent = [line for line in output.splitlines() if line.startswith("SENT ")]
    assert sent == [f"SENT ['( test -e {DAEMON_JSON} && cat {DAEMON_JSON} ) || echo __pyinfra_missing_{DAEMON_JSON}']"]
