"""git as the robot runs it against the fleet remote: one process, bounded
in time (``run``), and over SSH (``over_ssh``) with the ssh of
robotfleet/pull/robot/ssh_options.py (the pinned host keys, the robot's
keys, its narrowed offer), whose ``-E`` log gives ssh's own count of the
bytes ("Transferred: sent N, received M bytes") and names the key the
server accepted.

The wake's exchanges (robotfleet/pull/robot/transport.py) run git through here,
the probe of an SSH remote (``ls_remote``) among them.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import tempfile
import threading
import time
from dataclasses import dataclass

from robotfleet.pull.robot import probe, ssh_options

IDENTITY = {
    "GIT_AUTHOR_NAME": "robot-pull",
    "GIT_AUTHOR_EMAIL": "robot-pull@localhost",
    "GIT_COMMITTER_NAME": "robot-pull",
    "GIT_COMMITTER_EMAIL": "robot-pull@localhost",
}
# What ssh and the server say of the cause, before git's own summary line.
CAUSES = (
    "Permission denied",
    "Host key verification failed",
    "REMOTE HOST IDENTIFICATION HAS CHANGED",
    "Could not resolve",
    "Connection refused",
    "Connection timed out",
    "No route to host",
    # the server dropped the connection before a login: its MaxStartups, or OpenSSH >= 9.8's
    # PerSourcePenalties refusing this address after failed logins (docs/guides/pull.md)
    "Connection reset by",
    "Connection closed by",
    "DENIED",
)
_SAYS = ("FATAL:", "fatal:", "ERROR:", "error:", "remote:")
# --heads: protocol v2 then asks for refs/heads/ only, not every report ref
LS_REMOTE = ("-c", "protocol.version=2", "ls-remote", "--heads")
_TRANSFERRED = re.compile(r"Transferred: sent (\d+), received (\d+) bytes")
_ACCEPTED = re.compile(r"Authenticated to .* using \"publickey\"|Server accepts key: (\S+)")


class NoAnswer(Exception):
    """git did not end within its time (its process group is killed)."""


def environment(extra: dict | None = None) -> dict:
    """git's environment: this process's, no prompt, C messages, the agent's identity, ``extra``."""
    return dict(os.environ, GIT_TERMINAL_PROMPT="0", LC_ALL="C", **IDENTITY, **(extra or {}))


def keys(etc: str) -> list[str]:
    """The keys the robot offers: its own, then a first-boot bundle's enrollment key while it has one."""
    own, enroll = f"{etc}/id_ed25519", f"{etc}/enroll_ed25519"
    return [key for key in (own, enroll) if os.path.exists(key)]


def git_error(stderr: str, code: int) -> str:
    """The line of git's (or ssh's, or the server's) complaint that says why."""
    lines = [line.strip() for line in stderr.splitlines() if line.strip() and not line.startswith("hint:")]
    causes = [line for line in lines if any(cause in line for cause in CAUSES)]
    said = [line for line in lines if line.startswith(_SAYS)]
    return (causes or said or lines or [f"git exited {code}"])[0][:300]


def read_ssh_log(text: str) -> tuple[int, int, str | None]:
    """(bytes sent, bytes received, the key the server accepted) from ssh's log."""
    sent = received = 0
    for match in _TRANSFERRED.finditer(text):
        sent += int(match.group(1))
        received += int(match.group(2))
    accepted = [m.group(1) for m in _ACCEPTED.finditer(text) if m.group(1)]
    return sent, received, accepted[-1] if accepted else None


def no_answer(url: str, timeout: float) -> str:
    return f"no answer from {url} within {timeout} s (pull_fetch_timeout)"


def run(argv: list[str], env: dict, stdin: bytes | None, timeout: float, drain=None) -> tuple[int, bytes, bytes]:
    """(exit code, stdout, stderr) of ``argv``, in its own process group;
    ``drain``: a function that reads its stderr as it streams (then the
    stderr returned is empty).  NoAnswer after ``timeout`` seconds, the
    group killed; OSError when it cannot start."""
    process = subprocess.Popen(
        argv,
        stdin=subprocess.PIPE if stdin else None,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=env,
        start_new_session=True,
    )
    reader = None
    if drain is not None:
        reader = threading.Thread(target=drain, args=(process.stderr,), daemon=True)
        reader.start()
    try:
        out, err = _communicate(process, stdin, timeout, reader)
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        process.wait()
        raise NoAnswer from None
    return process.returncode, out, err


def _communicate(process, stdin: bytes | None, timeout: float, reader: threading.Thread | None):
    """``process.communicate``, or, while ``reader`` drains its stderr, the
    same for stdin and stdout alone; TimeoutExpired after ``timeout``."""
    if reader is None:
        return process.communicate(stdin, timeout=timeout)
    deadline = time.monotonic() + timeout
    if stdin:
        process.stdin.write(stdin)
        process.stdin.close()
    chunks: list[bytes] = []
    out = threading.Thread(target=lambda: chunks.extend(iter(lambda: process.stdout.read(65536), b"")), daemon=True)
    out.start()
    process.wait(timeout=max(0.0, deadline - time.monotonic()))
    for thread in (out, reader):
        thread.join(max(0.0, deadline - time.monotonic()))
    return b"".join(chunks), b""


@dataclass
class Ran:
    """What one git command over SSH did: its stdout, why it failed (one
    line; None: it did not), its bytes each way, the key the server
    accepted, its seconds."""

    out: bytes
    error: str | None
    sent: int
    received: int
    accepted: str | None
    seconds: float


def over_ssh(
    repo, args, url: str, etc: str, timeout: float, stdin: bytes | None = None, env=None, keepalive=None
) -> Ran:
    """git ``args`` in the repository ``repo``, talking to ``url`` with the
    robot's ssh (``etc``: its keys and known_hosts; ``keepalive``: its
    ServerAliveInterval and ServerAliveCountMax); never raises."""
    started = time.monotonic()
    sent = received = 0
    accepted, out, error = None, b"", None
    try:
        log = _log_file()
    except OSError as failed:
        return Ran(out, f"cannot make ssh's log ({failed})", sent, received, accepted, 0.0)
    try:
        command = ssh_options.ssh_command(
            keys(etc), f"{etc}/known_hosts", log, timeout, keepalive or ssh_options.KEEPALIVE
        )
        code, out, err = run(
            ["git", "-C", str(repo), *args], environment({**(env or {}), "GIT_SSH_COMMAND": command}), stdin, timeout
        )
    except NoAnswer:
        error = no_answer(url, timeout)
    except OSError as failed:
        error = f"cannot run git ({failed})"
    finally:
        try:
            with open(log, errors="replace") as file:
                text = file.read()
        except OSError:
            text = ""
        try:
            os.unlink(log)
        except OSError:
            pass
        sent, received, accepted = read_ssh_log(text)
    if error is None and code:
        # with -E, ssh's own complaint goes to its log, not to git's stderr
        ssh_said = "\n".join(line for line in text.splitlines() if any(c in line for c in CAUSES))
        error = git_error(err.decode(errors="replace") + "\n" + ssh_said, code)
    return Ran(out, error, sent, received, accepted, time.monotonic() - started)


def ls_remote(repo, url: str, branch: str, etc: str, timeout: float, keepalive=ssh_options.KEEPALIVE) -> probe.Answer:
    """The probe of a remote over SSH (robotfleet/pull/robot/probe.py): ``git
    ls-remote --heads`` of the one branch (one session: protocol v2's
    ``ls-refs`` for refs/heads/ only).  An answer with an ``error`` is the
    fetch's failure, as it would be git's."""
    ran = over_ssh(repo, [*LS_REMOTE, url, branch], url, etc, timeout, keepalive=keepalive)
    commit = probe.commit_of(ran.out, f"refs/heads/{branch}") if ran.error is None else None
    return probe.Answer(commit, sent=ran.sent, received=ran.received, error=ran.error, accepted=ran.accepted)


def _log_file() -> str:
    """A new file only this user can read, for ssh's log."""
    descriptor, path = tempfile.mkstemp(prefix="robot-pull-ssh-", suffix=".log")
    os.close(descriptor)
    return path
