"""SSH keepalives that give up: OpenSSH's ServerAliveInterval and
ServerAliveCountMax for the connections the tool opens itself (paramiko's,
robotfleet/connect.py) and for the ``ssh`` its git runs (a pull robot's:
robotfleet/pull/robot/ssh_options.py; the operator's: ``git_environment``).

A frozen link (a cell hand-over, a stalled tunnel) keeps the TCP
connection open and delivers nothing: TCP never reports it, and a read
waits for ever.  paramiko's own ``set_keepalive`` only sends; here each
keepalive asks for an answer (``keepalive@openssh.com``, which every server
answers, if only with a refusal), and when the server has not answered for
``count_max`` intervals the transport ends with ``Frozen``: its channels
close, so the command waiting on one returns, and the host fails with the
reason (robotfleet/reasons.py ``frozen``).  No paramiko import here: a
pull robot's agent reads its defaults and options without it."""

from __future__ import annotations

import functools
import subprocess
import threading
import time

REQUEST = "keepalive@openssh.com"
# (interval, count_max): robotfleet/fleet/connection.py's defaults, a link silent for a minute given up.
DEFAULT = (15, 3)


class Frozen(TimeoutError):
    """The server stopped answering; ``seconds`` since the unanswered keepalive was sent.  An OSError
    without arguments, as paramiko's transport thread words a socket's error (str: the message)."""

    def __init__(self, seconds: float, interval: int, count_max: int):
        super().__init__()
        self.seconds, self.interval, self.count_max = seconds, interval, count_max

    def __str__(self) -> str:
        return f"no answer for {self.seconds:.0f} s"


class Watch:
    """The keepalives of one paramiko ``transport``.  paramiko calls ``tick``
    from its transport thread once ``interval`` seconds passed without a
    write, when a read found nothing (the socket's timeout: at most the
    interval, robotfleet/connect.py ``idle_wakeup``).  One keepalive is asked
    at a time, from a thread of its own (the transport thread reads the
    answer; a write stuck on the frozen link must not hold it)."""

    def __init__(self, transport, interval: int, count_max: int):
        self.transport, self.interval, self.count_max = transport, interval, count_max
        self.unanswered = 0
        self.asked_at = 0.0
        self.asking: threading.Thread | None = None
        self.frozen: Frozen | None = None  # why it ended, once it has
        transport.packetizer.set_keepalive(interval, self.tick)

    def tick(self) -> None:
        if self.asking is not None and self.asking.is_alive():
            self.unanswered += 1
            if self.unanswered >= self.count_max:
                self.frozen = Frozen(time.monotonic() - self.asked_at, self.interval, self.count_max)
                raise self.frozen
            return
        self.unanswered = 0
        self.asked_at = time.monotonic()
        self.asking = threading.Thread(target=self._ask, name="ssh-keepalive", daemon=True)
        self.asking.start()

    def _ask(self) -> None:
        try:  # returns on the answer (a refusal counts) or when the transport ends
            self.transport.global_request(REQUEST, wait=True)
        except Exception:  # the transport ended while it was sent: the transport thread tells why
            pass


def openssh_options(interval: int, count_max: int) -> list[str]:
    """The same bound for OpenSSH's ``ssh``: its -o options."""
    return ["-o", f"ServerAliveInterval={interval}", "-o", f"ServerAliveCountMax={count_max}"]


def silence(keepalive: tuple[int, int]) -> int:
    """The seconds without an answer after which ``keepalive`` gives a connection up (OpenSSH's rule:
    ServerAliveCountMax + 1 intervals); HTTPS exchanges are allowed as long."""
    interval, count_max = keepalive
    return interval * (count_max + 1)


def git_environment(env: dict, where: str, keepalive: tuple[int, int] = DEFAULT) -> dict:
    """``env`` for the operator's git in the repository ``where``, whose ssh
    (to a fleet remote) then gives up on a frozen server as the connector
    does; unless the user chose the ssh git runs (GIT_SSH_COMMAND, GIT_SSH,
    core.sshCommand), which is left as it is."""
    if "GIT_SSH_COMMAND" in env or "GIT_SSH" in env or _ssh_configured(where):
        return env
    return {**env, "GIT_SSH_COMMAND": " ".join(["ssh", *openssh_options(*keepalive)])}


@functools.lru_cache(maxsize=64)
def _ssh_configured(where: str) -> bool:
    try:
        asked = subprocess.run(
            ["git", "-C", where, "config", "--get", "core.sshCommand"], capture_output=True, timeout=30, check=False
        )
    except (OSError, subprocess.TimeoutExpired):
        return False
    return bool(asked.stdout.strip())
