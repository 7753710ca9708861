"""End to end: a laptop deploying itself (inventories/local.py) as a user
whose sudo needs a password (issue 28, item 8).  It printed pyinfra's
2,700-character traceback from a password prompt it could not show; now one
line names the host, that sudo needs a password and the two ways on, and
each way on works: --use-sudo-password with the password on stdin, the
sudoers line the message prints, and in a terminal sudo's own prompt, once.

The session's stock Debian 13 container with this checkout set up
(`stock_machine`, tests/e2e/stock_machine.py: sudo, python3) gets a user
`dev`; the deploys run as dev with --dry (the snapshot and every sudo
command run, nothing changes)."""

from __future__ import annotations

import pytest

from tests.e2e.stock_machine import quote

pytestmark = pytest.mark.e2e

FLEET = """\
all:
  vars: {payload_image: "reg.example.com/ros/payload:1.0"}
laptops:
  hosts:
    devbox: {x11_user: dev, docker_users: [dev]}
"""
DEPLOY = "env ROBOT_FLEET=/tmp/fleet.yaml PYINFRA_PROGRESS=off .venv/bin/pyinfra --dry inventories/local.py deploy.py"
LINE = (
    "[@local] sudo needs a password for dev, and there is no terminal to ask for it: run pyinfra with "
    "--use-sudo-password (it asks once, from stdin without a terminal, and hands the password to sudo through "
    "SUDO_ASKPASS), or let dev use sudo without one: echo 'dev ALL=(ALL:ALL) NOPASSWD: ALL' | sudo tee "
    "/etc/sudoers.d/robotfleet (then sudo visudo -cf /etc/sudoers.d/robotfleet; remove it after the deploy)"
)


# A person at a terminal: the command runs in a pseudo-terminal and each of
# sudo's prompts gets the answer once it shows (echo is off by then), the
# last answer again for every further prompt; cut after 600 s (exit 124).
# `script` fed from a pipe raced sudo: a line typed ahead was echoed or
# flushed, and after a wrong password the EOF meant for its second prompt was
# flushed too, so sudo waited for ever (CI, 2026-11-27).
TERMINAL = r"""
import os, pty, select, signal, sys, time
answers = [answer.encode() + b"\n" for answer in sys.argv[2:]]
pid, fd = pty.fork()
if pid == 0:
    os.execvp("sh", ["sh", "-c", sys.argv[1]])
out, answered, deadline = b"", 0, time.monotonic() + 600
while time.monotonic() < deadline:
    if not select.select([fd], [], [], 1)[0]:
        continue
    try:
        chunk = os.read(fd, 4096)
    except OSError:
        chunk = b""
    if not chunk:
        break
    out += chunk
    while out.count(b"password for ") > answered:
        os.write(fd, answers[min(answered, len(answers) - 1)])
        answered += 1
else:
    os.killpg(pid, signal.SIGKILL)
    out += b"\n(still running after 600 s: killed)\n"
_, status = os.waitpid(pid, 0)
sys.stdout.write(out.decode(errors="replace").replace("\r\n", "\n"))
sys.exit(124 if time.monotonic() >= deadline else os.waitstatus_to_exitcode(status))
"""
IN_TERMINAL = ".venv/bin/python -c " + quote(TERMINAL)  # then the command, then the answers


@pytest.fixture(scope="module")
def laptop(stock_machine):
    code, out = stock_machine.setup
    assert code == 0, out[-4000:]
    code, out = stock_machine.sh(
        "useradd -m dev && echo 'dev:s3cret-pw' | chpasswd && chmod -R a+rX /w && "
        f"printf '%s' {quote(FLEET)} > /tmp/fleet.yaml && chmod a+r /tmp/fleet.yaml"
    )
    assert code == 0, out
    yield stock_machine.sh
    stock_machine.sh("userdel -r dev; rm -f /tmp/fleet.yaml")


def test_no_sudo_rights_and_no_terminal_is_one_line(laptop):
    code, out = laptop(f"{DEPLOY} < /dev/null 2>&1", user="dev")
    assert code == 1, out
    assert out.splitlines() == ["--> Loading config...", "--> Loading inventory...", LINE]


def test_each_way_on_works(laptop):
    code, out = laptop("echo 'dev ALL=(ALL:ALL) ALL' > /etc/sudoers.d/dev && chmod 440 /etc/sudoers.d/dev")
    assert code == 0, out
    try:
        code, out = laptop(f"{DEPLOY} < /dev/null 2>&1", user="dev")  # sudo with a password, no terminal
        assert (code, out.splitlines()[-1]) == (1, LINE), out

        # 1. --use-sudo-password, the password on stdin
        code, out = laptop(f"echo s3cret-pw | {DEPLOY} --use-sudo-password 2>&1", user="dev")
        assert code == 0 and "Detected changes" in out, out[-3000:]

        # 2. in a terminal: sudo asks once, itself; pyinfra never asks (the password stays off argv)
        code, out = laptop(f"{IN_TERMINAL} {quote(DEPLOY)} s3cret-pw", user="dev")
        assert code == 0 and "Detected changes" in out, out[-3000:]
        assert out.count("[sudo] password for dev") == 1 and "sudo password:" not in out, out[:2000]
        code, out = laptop(f"sudo -k; {IN_TERMINAL} {quote(DEPLOY)} wrong", user="dev")
        assert code == 1 and out.splitlines()[-1].startswith(
            "[@local] sudo refused dev (a wrong password, or dev may not use sudo)"
        ), out[-2000:]
        assert out.count("[sudo] password for dev") == 3, out[-2000:]  # sudo's own three tries, then the line

        # 3. the sudoers line the message prints, as it is
        line = LINE.split("echo '", 1)[1].split("'", 1)[0]
        code, out = laptop(
            f"echo {quote(line)} > /etc/sudoers.d/robotfleet && chmod 440 /etc/sudoers.d/robotfleet "
            "&& visudo -cf /etc/sudoers.d/robotfleet"
        )
        assert code == 0, out
        code, out = laptop(f"sudo -k; {DEPLOY} < /dev/null 2>&1", user="dev")
        assert code == 0 and "Detected changes" in out, out[-3000:]
    finally:
        laptop("rm -f /etc/sudoers.d/dev /etc/sudoers.d/robotfleet")
