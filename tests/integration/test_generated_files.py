"""The payload unit a fresh robot is sent (tests/unit/test_generated_files.py)
checked by systemd itself: `systemd-analyze verify` on this machine."""

import shutil
import subprocess
from pathlib import Path

import pytest

from tests.unit.samples import UNIT


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
        capture_output=True,
        text=True,
        timeout=60,
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
