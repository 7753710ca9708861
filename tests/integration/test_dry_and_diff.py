"""pyinfra's real CLI with `--dry` and `--diff` (tests/unit/test_dry_and_diff.py
plans the same in process): @fake hosts answered by the unit harness, in a
fresh interpreter, as an operator runs it."""

import os

from tests.fixtures import ROOT, pyinfra
from tests.integration.operator_side import dry_run
from tests.unit.harness import ROBOT
from tests.unit.samples import DAEMON_JSON


def test_pyinfra_dry_names_the_reason_and_exits_1(tmp_path):
    dry_run(tmp_path)


# The drifted robot, and what the recorder was sent printed as pyinfra exits
DRIFTED_HOST = """
import atexit
from tests.unit.harness import _Recorder
from tests.unit.samples import DAEMON_JSON, DRIFTED, drifted_robot
recorder = _Recorder({"r1": drifted_robot()}, {"r1": {DAEMON_JSON: DRIFTED}}).__enter__()
atexit.register(lambda: print("SENT", [str(c) for c in recorder.sent["r1"]]))
"""


def test_pyinfra_dry_diff_prints_the_drifted_file(tmp_path):
    inventory = tmp_path / "fake.py"
    host = {**ROBOT, "fake_delay": 0, "fake_delay_jitter": 0}
    inventory.write_text(f"robots = [('@fake/r1', {host!r})]\n")
    env = dict(os.environ, PYTHONPATH=str(ROOT), PYINFRA_PROGRESS="off")
    proc = pyinfra("--dry", "--diff", str(inventory), "deploy.py", env=env, timeout=300, setup=DRIFTED_HOST)
    output = proc.stdout + proc.stderr
    assert proc.returncode == 0, output[-3000:]
    assert f"[@fake/r1] Will modify {DAEMON_JSON}" in output
    assert '-  "live-restore": false' in output and '+  "live-restore": true,' in output
    # The one thing sent besides the snapshot is the read of that file.
    sent = [line for line in output.splitlines() if line.startswith("SENT ")]
    assert sent == [f"SENT ['( test -e {DAEMON_JSON} && cat {DAEMON_JSON} ) || echo __pyinfra_missing_{DAEMON_JSON}']"]
