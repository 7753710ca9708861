"""The files a fresh robot is sent, compared byte for byte with reviewed
copies in tests/unit/golden/, and the payload unit checked by systemd itself.

The converged-host tests build their snapshots with the production
renderers, so they prove consistency only; these prove content.  After an
intended change, regenerate and review the diff:

    ROBOT_REGENERATE_GOLDEN=1 python3 -m pytest tests/unit/test_generated_files.py
"""

import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest

from roles.payload.payloadctl.releases import compose_yaml
from tests.unit.harness import find, fresh_host, plan, written_files
from tests.unit.harness import ROBOT

GOLDEN = Path(__file__).resolve().parent / "golden"
REGENERATE = os.environ.get("ROBOT_REGENERATE_GOLDEN") == "1"
UNIT = "/etc/systemd/system/robot-payload.service"


@pytest.fixture(scope="module")
def sent_to_a_fresh_robot():
    commands = plan({"robot1": ("robots", {
        **ROBOT, "ssh_hostname": "10.20.0.11",
        "docker_registry_mirrors": ["https://mirror.lan"], "docker_insecure_registries": ["registry.lan:5000"],
    }, fresh_host("debian-13"))})["robot1"]
    files = written_files(commands)
    release = find(commands, "payloadctl apply")
    assert len(release) == 1
    files["compose.yaml"] = compose_yaml(json.loads(release[0].stdin)["spec"]["compose"])
    return files


@pytest.mark.parametrize("golden, sent", [
    ("daemon.json", "/etc/docker/daemon.json"),
    ("robot-payload.service", UNIT),
    ("70-robot-sensors.rules", "/etc/udev/rules.d/70-robot-sensors.rules"),
    ("compose.yaml", "compose.yaml"),
])
def test_sent_file_matches_its_golden_copy(sent_to_a_fresh_robot, golden, sent):
    content = sent_to_a_fresh_robot[sent]
    path = GOLDEN / golden
    if REGENERATE:
        path.write_text(content)
    assert content == path.read_text(), f"{sent} differs from tests/unit/golden/{golden} (ROBOT_REGENERATE_GOLDEN=1 to accept)"


def systemd_verify(unit_text: str, root: Path) -> subprocess.CompletedProcess:
    """``systemd-analyze verify`` on the unit inside a scratch root holding
    this machine's system units and stand-ins for the unit's executables."""
    shutil.copytree("/usr/lib/systemd/system", root / "usr/lib/systemd/system", symlinks=True)
    unit = root / UNIT.lstrip("/")
    unit.parent.mkdir(parents=True)
    unit.write_text(unit_text)
    for line in unit_text.splitlines():
        key, _, value = line.partition("=")
        if key.startswith("Exec") and value:
            executable = root / value.split()[0].lstrip("-@+!").lstrip("/")
            executable.parent.mkdir(parents=True, exist_ok=True)
            executable.write_text("#!/bin/sh\n")
            executable.chmod(0o755)
    return subprocess.run(
        ["systemd-analyze", "verify", "--man=no", "--generators=no", f"--root={root}", UNIT],
        capture_output=True, text=True, timeout=60,
    )


def _verify_or_skip(unit_text, root):
    if not shutil.which("systemd-analyze"):
        pytest.skip("systemd-analyze is not installed here (apt-get install systemd)")
    if not Path("/usr/lib/systemd/system/multi-user.target").exists():
        pytest.skip("this machine has no systemd units to verify against")
    return systemd_verify(unit_text, root)


def test_payload_unit_passes_systemd_analyze_verify(sent_to_a_fresh_robot, tmp_path):
    result = _verify_or_skip(sent_to_a_fresh_robot[UNIT], tmp_path)
    assert (result.returncode, result.stdout + result.stderr) == (0, "")


def test_systemd_analyze_verify_catches_a_broken_unit(sent_to_a_fresh_robot, tmp_path):
    broken = sent_to_a_fresh_robot[UNIT].replace("Type=oneshot", "Type=oneshoot")
    result = _verify_or_skip(broken, tmp_path)
    assert "Failed to parse service type" in result.stderr
