"""The lab's docker exec script (tests/lab/state.py) run by a real shell
here: the command's output and exit code come through its file and end
mark, and the files of earlier commands are swept once there are many,
only those older than a minute."""

from __future__ import annotations

import os
import subprocess
import time

import pytest

from tests.lab import state

pytestmark = pytest.mark.integration


def run(argv: list[str]) -> tuple[int, str]:
    done = subprocess.run(argv, capture_output=True, text=True)
    return done.returncode, done.stdout


def test_the_output_and_exit_code_come_through_the_file(tmp_path):
    out = tmp_path / "lab-exec-1"
    code, streamed = run(state.exec_argv("echo 'a b'; echo err >&2; exit 3", str(out)))
    assert code == 3
    assert state.exec_output(streamed) == "a b\nerr\n" == out.read_text()


def test_old_files_are_swept_once_there_are_many_and_recent_ones_kept(tmp_path):
    old = time.time() - 120
    for number in range(state.EXEC_KEEP):
        path = tmp_path / f"lab-exec-old{number}"
        path.write_text("x")
        os.utime(path, (old, old))
    recent = tmp_path / "lab-exec-recent"
    recent.write_text("y")
    other = tmp_path / "not-ours"
    other.write_text("z")
    os.utime(other, (old, old))
    code, streamed = run(state.exec_argv(["true"], str(tmp_path / "lab-exec-now")))
    assert (code, state.exec_output(streamed)) == (0, "")
    assert sorted(path.name for path in tmp_path.iterdir()) == ["lab-exec-now", "lab-exec-recent", "not-ours"]


def test_a_few_files_are_left_alone(tmp_path):
    old = time.time() - 120
    for number in range(3):
        path = tmp_path / f"lab-exec-old{number}"
        path.write_text("x")
        os.utime(path, (old, old))
    run(state.exec_argv(["true"], str(tmp_path / "lab-exec-now")))
    assert len(list(tmp_path.iterdir())) == 4
