"""The robot's own key for the fleet remote (robotfleet/pull/protocol/robot_key.py):
the one script the pull role and a first-boot bundle run, run here with a
real ssh-keygen in a directory standing for /etc/robot-pull."""

from __future__ import annotations

import os
import subprocess

from robotfleet.pull.operator import bundle
from robotfleet.pull.protocol import agent_files, robot_key
from roles.pull import plan


def run(script: str, etc, path: str | None = None) -> subprocess.CompletedProcess:
    env = {**os.environ, "PATH": path or os.environ["PATH"]}
    return subprocess.run(
        ["sh", "-c", script.replace(agent_files.ETC, str(etc))], capture_output=True, text=True, env=env
    )


def test_the_key_pair_is_made_private_under_its_name_and_nothing_else_is_left(tmp_path):
    done = run(plan.keygen_script("robot$(id) 1"), tmp_path)
    assert done.returncode == 0, done.stderr
    key, public = tmp_path / "id_ed25519", tmp_path / "id_ed25519.pub"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["id_ed25519", "id_ed25519.pub"]
    assert public.read_text().split()[2:] == ["robot-pull@robot$(id)", "1"]  # a name is data, never run
    assert key.stat().st_mode & 0o077 == 0 and public.stat().st_mode & 0o077 == 0


def test_a_failed_keygen_leaves_no_key_and_no_temp_directory(tmp_path):
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    (bin_dir / "ssh-keygen").write_text("#!/bin/sh\nexit 1\n")
    (bin_dir / "ssh-keygen").chmod(0o755)
    etc = tmp_path / "etc"
    etc.mkdir()
    done = run(robot_key.keygen_script("robot-pull@r1"), etc, f"{bin_dir}:{os.environ['PATH']}")
    assert done.returncode != 0
    assert list(etc.iterdir()) == []


def test_the_first_boot_names_the_key_after_the_robot_in_its_config(tmp_path):
    assert robot_key.keygen_script(bundle.KEY_COMMENT) in bundle.FIRST_BOOT_SCRIPT
    (tmp_path / "agent.json").write_text('{"interval": 60, "robot": "robot9"}')
    done = run(robot_key.keygen_script(bundle.KEY_COMMENT), tmp_path)  # reads <tmp_path>/agent.json
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "id_ed25519.pub").read_text().split()[2] == "robot-pull@robot9"
