"""Long work shows its progress (issue 54, item 4): on a terminal (a real
pseudo-terminal here) status, enroll and rollout draw one progress line on
stderr (done/total, failures, the wave, time left) and status colours its
table; in a pipe, with --json or with NO_COLOR there is none of it; a fleet
file's notes are told once there.  A fleet of robots on a closed port of
127.0.0.1."""

from __future__ import annotations

import os
import pty
import re
import select
import subprocess
import sys
import time

import pytest

from robotfleet.fleet import yaml12
from tests.fixtures import ROOT
from tests.integration import sshserver

ROBOTS = 30
BAR = "━"
DRAWN = "[━╸╺]+"  # the bar: done, its tip, what is left
COLOUR = re.compile(r"\x1b\[[0-9;]*m")  # any style
COLOURED = re.compile(r"\x1b\[(?:[0-9;]*;)?(?:3[0-8]|9[0-7])[;m]")  # a colour (NO_COLOR leaves bold)


@pytest.fixture
def fleet(tmp_path):
    path = tmp_path / "fleet.yaml"
    settings = {
        "payload_image": "reg.example.com/p:1",
        "ssh_user": "ops",
        "ssh_port": sshserver.closed_port(),
        "ssh_known_hosts_file": str(tmp_path / "known_hosts"),
        "ssh_connect_timeout": 2,
        "ssh_connect_retries": 0,
    }
    (tmp_path / "known_hosts").write_text("")
    hosts = {f"robot{i}": {"address": "127.0.0.1"} for i in range(ROBOTS)}
    path.write_text(yaml12.dump({"all": {"vars": settings}, "robots": {"hosts": hosts}}))
    return path


def environment(tmp_path, **more) -> dict[str, str]:
    env = {"PATH": "/usr/bin:/bin", "HOME": str(tmp_path), "TERM": "xterm-256color", "COLUMNS": "120"}
    env.update(ROBOT_ROLLOUT_DIR=str(tmp_path / "rollouts"), PYINFRA_PROGRESS="off", **more)
    return env


def on_a_terminal(argv, env, timeout=120) -> tuple[int, str]:
    """``argv`` with stdin, stdout and stderr on one pseudo-terminal: (exit status, what it showed)."""
    main, sub = pty.openpty()
    proc = subprocess.Popen(argv, stdin=sub, stdout=sub, stderr=sub, env=env, cwd=ROOT, close_fds=True)
    os.close(sub)
    shown, end = b"", time.monotonic() + timeout
    while time.monotonic() < end:
        ready, _, _ = select.select([main], [], [], 0.5)
        if ready:
            try:
                data = os.read(main, 65536)
            except OSError:  # the terminal's other end closed: the process is done
                break
            if not data:
                break
            shown += data
        elif proc.poll() is not None:
            break
    os.close(main)
    return proc.wait(timeout=10), shown.decode(errors="replace")


def robotfleet(*args) -> list[str]:
    return [sys.executable, "-m", "robotfleet", *args]


def test_status_on_a_terminal_draws_one_progress_line_and_colours(tmp_path, fleet):
    code, shown = on_a_terminal(robotfleet("status", str(fleet)), environment(tmp_path))
    assert code == 3, shown[-2000:]
    plain = COLOUR.sub("", shown)
    assert re.search(rf"status {DRAWN} +\d+/{ROBOTS} hosts, \d+ failed, left", plain), plain[:2000]
    assert "[robot3] unreachable: connection refused by 127.0.0.1" in plain  # above the line, once each
    assert not re.search(r"\(\d+/30\)", plain)  # not a line per host with its count, as in a pipe
    table = shown[shown.index("HOST") :]
    assert "\x1b[35mrobot0\x1b[0m" in table and "30 unreachable" in plain  # unreachable hosts' colour
    assert plain.rstrip().endswith("30 unreachable")


def test_no_colour_with_no_color_and_no_progress_line_with_json(tmp_path, fleet):
    code, shown = on_a_terminal(robotfleet("status", str(fleet)), environment(tmp_path, NO_COLOR="1"))
    assert code == 3
    table = shown[shown.index("HOST") :]
    assert not COLOURED.search(table), table[:500]
    code, shown = on_a_terminal(robotfleet("status", str(fleet), "--json"), environment(tmp_path))
    assert code == 3 and BAR not in shown
    assert "[robot0] unreachable: " in shown  # the lines as each host answers, as before


def test_in_a_pipe_nothing_of_it(tmp_path, fleet):
    result = subprocess.run(
        robotfleet("status", str(fleet)), cwd=ROOT, env=environment(tmp_path), capture_output=True, text=True
    )
    assert result.returncode == 3
    assert BAR not in result.stderr and not COLOUR.search(result.stdout + result.stderr)
    assert len(re.findall(r"^\[robot\d+\] unreachable: .* \(\d+/30\)$", result.stderr, re.M)) == ROBOTS
    assert result.stdout.splitlines()[-1] == "30 unreachable"


def test_enroll_and_a_rollout_on_a_terminal(tmp_path, fleet):
    code, shown = on_a_terminal(robotfleet("enroll", str(fleet), "--yes"), environment(tmp_path))
    assert code == 3, shown[-2000:]
    assert re.search(rf"enroll {DRAWN} +\d+/{ROBOTS} hosts, \d+ failed", COLOUR.sub("", shown)), shown[:2000]
    code, shown = on_a_terminal(robotfleet("rollout", str(fleet), "--batch", "50%", "-y"), environment(tmp_path))
    plain = COLOUR.sub("", shown)
    assert code == 3, plain[-2000:]
    assert re.search(rf"rollout {DRAWN} +\d+/{ROBOTS} robots, 0 failed, wave 2/3, left", plain), plain[-3000:]


def test_a_fleet_files_notes_are_told_once_on_a_terminal(tmp_path, fleet):
    """Ansible's own variables are ignored, and said so once per fleet file on a terminal (remembered in the
    user's cache), every time in a pipe or a log, and by robotfleet inventory always (issue 54, item 3)."""
    fleet.write_text(fleet.read_text().replace("ssh_user: ops", "ssh_user: ops\n    ansible_become: true"))
    note = "note: ansible_become: Ansible's own, ignored here"
    env = environment(tmp_path)
    told = [on_a_terminal(robotfleet("status", str(fleet), "--limit", "robot1"), env)[1] for _ in range(2)]
    assert note in told[0] and "(said once for this fleet; robotfleet inventory" in told[0], told[0][:2000]
    assert note not in told[1], told[1][:2000]
    assert list((tmp_path / ".cache" / "robotfleet" / "notes-told").iterdir())
    code, shown = on_a_terminal(robotfleet("inventory", str(fleet), "--graph"), env)
    assert code == 0 and note in shown
    for _ in range(2):
        piped = subprocess.run(
            robotfleet("status", str(fleet), "--limit", "robot1"), cwd=ROOT, env=env, capture_output=True, text=True
        )
        assert note in piped.stderr
