"""A laptop deploying itself (inventories/local.py) runs every step through
sudo.  Before pyinfra starts, this asks sudo whether it will do so without a
password (``sudo -n true``), so that a user whose sudo needs one is told in
one line, not with pyinfra's traceback from a password prompt it could not
show (2,700 characters where no terminal is attached):

- in a terminal, sudo asks once for the password (``sudo -v``, sudo's own
  prompt; the password stays with sudo) and the deploy's steps then use
  sudo's cached credentials; a refusal (wrong password, a user who may not
  use sudo) is one line;
- with no terminal (a script, CI), one line naming the host, that sudo
  needs a password, and the two ways on: ``--use-sudo-password`` (pyinfra
  asks once, from stdin when there is no terminal, and hands it to sudo
  through SUDO_ASKPASS), or a sudoers line that lets the user run sudo
  without one.
"""

from __future__ import annotations

import getpass
import os
import subprocess
import sys

PASSWORD_LINES = ("a password is required", "interactive authentication is required")  # sudo, sudo-rs
SUDOERS_FILE = "/etc/sudoers.d/robotfleet"
FAILED = 1  # README: a host failed


def sudoers_line(user: str) -> str:
    return f"{user} ALL=(ALL:ALL) NOPASSWD: ALL"


def needs_password_line(host: str, user: str) -> str:
    return (
        f"[{host}] sudo needs a password for {user}, and there is no terminal to ask for it: run pyinfra with "
        "--use-sudo-password (it asks once, from stdin without a terminal, and hands the password to sudo "
        f"through SUDO_ASKPASS), or let {user} use sudo without one: echo '{sudoers_line(user)}' | sudo tee "
        f"{SUDOERS_FILE} (then sudo visudo -cf {SUDOERS_FILE}; remove it after the deploy)"
    )


def has_terminal() -> bool:
    """Whether there is a terminal to ask on: the controlling one, which
    sudo and getpass read a password from (stdin may be a terminal that is
    not, as under ``su -c``)."""
    try:
        with open("/dev/tty", "rb"):
            return True
    except OSError:
        return False


def probe() -> tuple[str, str]:
    """('ok' | 'password' | 'missing' | 'refused', what sudo said)."""
    try:
        done = subprocess.run(
            ["sudo", "-n", "true"], stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=30
        )
    except FileNotFoundError:
        return "missing", "sudo is not installed"
    except subprocess.TimeoutExpired:
        return "refused", "sudo -n true did not answer within 30 s"
    said = " ".join(done.stderr.split())
    if done.returncode == 0:
        return "ok", ""
    if any(line in said for line in PASSWORD_LINES):
        return "password", said
    return "refused", said or f"sudo -n true exited {done.returncode}"


def problem(host: str, user: str, verdict: str, said: str, terminal: bool) -> str | None:
    """The one line for what ``probe`` found, or None: go on (sudo works, or
    a terminal is there to ask for the password)."""
    if verdict == "ok" or (verdict == "password" and terminal):
        return None
    if verdict == "password":
        return needs_password_line(host, user)
    if verdict == "missing":
        return (
            f"[{host}] sudo is not installed, and every step runs through it: install it as root (apt-get install sudo)"
        )
    return f"[{host}] sudo refuses {user}: {said}"


def require(host: str = "@local") -> None:
    """Under pyinfra's CLI, as a user other than root without
    --use-sudo-password: make sure sudo will run the steps, or stop with one
    line (exit status 1, a host failed)."""
    import click

    context = click.get_current_context(silent=True)
    if context is None or os.geteuid() == 0 or context.params.get("use_sudo_password"):
        return
    user = getpass.getuser()
    verdict, said = probe()
    terminal = has_terminal()
    line = problem(host, user, verdict, said, terminal)
    if line is None and verdict == "password":
        print(f"[{host}] sudo needs {user}'s password once for this deploy:", file=sys.stderr, flush=True)
        if subprocess.run(["sudo", "-v"]).returncode != 0:
            line = (
                f"[{host}] sudo refused {user} (a wrong password, or {user} may not use sudo): run as a user "
                f"who may, or let {user} use sudo: echo '{sudoers_line(user)}' | sudo tee {SUDOERS_FILE} (as root)"
            )
    if line is not None:
        print(line, file=sys.stderr)
        sys.stderr.flush()
        os._exit(FAILED)
