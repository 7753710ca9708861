"""Labs started at once build an image tag once: the one that takes the
tag's machine-wide lock builds it, the other waits, then finds it built
(tests/lab/machinelock.py, as hostimage.ensure_host_image uses it)."""

import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
# One lab's "ensure the image": check, lock, check again, build (slowly) unless another lab did.
LAB = """
import sys, time
from pathlib import Path
from tests.lab.machinelock import machine_lock
work, name = Path(sys.argv[1]), sys.argv[2]
built = work / "image"
if not built.exists():
    with machine_lock("image robot-lab-host:1234"):
        if not built.exists():
            (work / "building").write_text(name)
            with open(work / "builds", "a") as log:
                log.write(name + "\\n")
            time.sleep(2)
            built.write_text(name)
print(name, "uses the image built by", built.read_text(), flush=True)
"""


def start(work: Path, name: str, locks: Path) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=str(ROOT), ROBOT_LAB_LOCK_DIR=str(locks))
    return subprocess.Popen(
        [sys.executable, "-c", LAB, str(work), name],
        cwd=ROOT,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )


def test_a_tag_another_lab_is_building_is_waited_for_then_used_not_built_again(tmp_path):
    locks = tmp_path / "locks"
    first = start(tmp_path, "lab-a", locks)
    deadline = time.monotonic() + 30
    while not (tmp_path / "building").exists():  # lab-a holds the lock and builds
        assert time.monotonic() < deadline and first.poll() is None, first.communicate()[0]
        time.sleep(0.05)
    second = start(tmp_path, "lab-b", locks)
    out_a, out_b = first.communicate(timeout=60)[0], second.communicate(timeout=60)[0]
    assert first.returncode == 0 and second.returncode == 0, out_a + out_b
    assert (tmp_path / "builds").read_text() == "lab-a\n"
    assert "lab: waiting for another lab's image robot-lab-host:1234 ..." in out_b, out_b
    assert "lab-b uses the image built by lab-a" in out_b, out_b
    assert [p.name for p in locks.iterdir()] == ["image_robot-lab-host_1234.lock"]
