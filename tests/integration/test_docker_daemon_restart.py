"""The docker role's restart script (roles/docker/daemon.py) run by sh with
systemctl and journalctl stand-ins on PATH (no systemd here): when Docker
refuses a daemon.json, the previous file is put back and the failure names
dockerd's own reason, even when journald writes dockerd's last line a moment
after systemd has recorded the failure (seen on a loaded lab robot: the
reason came out as "not active after 60 s")."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

from roles.docker.daemon import restart_script

REFUSAL = (
    "unable to configure the Docker daemon with file /etc/docker/daemon.json: the following directives are "
    "specified both as a flag and in the configuration file: hosts"
)
SYSTEMCTL = """#!/bin/sh
case "$1" in
    reset-failed) exit 0 ;;
    restart|is-active) grep -q hosts "$DEST" && exit 3; exit 0 ;;
esac
exit 0
"""
# Nothing the first time it is asked (journald behind), dockerd's line after.
JOURNALCTL = """#!/bin/sh
n=$(cat "$COUNT" 2>/dev/null || echo 0); echo $((n + 1)) > "$COUNT"
[ "$n" -ge "$LAG" ] && echo "$REFUSAL"
exit 0
"""


def run(tmp_path: Path, lag: int) -> subprocess.CompletedProcess:
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    for name, text in (("systemctl", SYSTEMCTL), ("journalctl", JOURNALCTL)):
        (bin_dir / name).write_text(text)
        (bin_dir / name).chmod(0o755)
    dest, previous, pending = tmp_path / "daemon.json", tmp_path / "daemon.json.previous", tmp_path / "pending"
    dest.write_text('{"hosts": ["unix:///var/run/docker.sock"]}\n')
    previous.write_text('{"live-restore": true}\n')
    pending.touch()
    env = {
        **os.environ,
        "PATH": f"{bin_dir}:{os.environ['PATH']}",
        "DEST": str(dest),
        "COUNT": str(tmp_path / "count"),
        "LAG": str(lag),
        "REFUSAL": REFUSAL,
    }
    script = restart_script("restart", 5, str(dest), str(previous), str(pending))
    return subprocess.run(["sh", "-c", script], capture_output=True, text=True, env=env, timeout=60)


@pytest.mark.parametrize("lag", [0, 2], ids=["at once", "a moment late"])
def test_a_refused_daemon_json_is_put_back_and_the_reason_is_dockerd_s(tmp_path, lag):
    result = run(tmp_path, lag)
    assert result.returncode == 1
    assert result.stderr.strip() == (
        f"docker: Docker did not start with the new daemon.json ({REFUSAL}); "
        "the previous daemon.json is restored and Docker runs again"
    )
    assert (tmp_path / "daemon.json").read_text() == '{"live-restore": true}\n'
    assert not (tmp_path / "daemon.json.previous").exists() and not (tmp_path / "pending").exists()


def test_without_a_line_from_dockerd_the_reason_is_the_timeout(tmp_path):
    result = run(tmp_path, lag=99)
    assert result.returncode == 1
    assert "(not active after 5 s at most (docker_restart_timeout)); the previous daemon.json is restored" in (
        result.stderr
    )
