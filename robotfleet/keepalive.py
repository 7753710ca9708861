"""SSH keepalives that give up: OpenSSH's ServerAliveInterval and
ServerAliveCountMax for the connections the tool opens itself (paramiko's,
robotfleet/connect.py) and the options for those it leaves to ``ssh``.

A frozen link (a cell hand-over, a stalled tunnel) keeps the TCP
connection open and delivers nothing: TCP never reports it, and a read
waits for ever.  paramiko's own ``set_keepalive`` only sends; here each
keepalive asks for an answer (``keepalive@openssh.com``, which every server
answers, if only with a refusal), and when the server has not answered for
``count_max`` intervals the transport ends with ``Frozen``: its channels
close, so the command waiting on one returns, and the host fails with the
reason (robotfleet/reasons.py ``frozen``)."""

from __future__ import annotations

import threading
import time

from paramiko import SSHException

REQUEST = "keepalive@openssh.com"


class Frozen(SSHException):
    """The server stopped answering; ``seconds`` since the unanswered keepalive was sent."""

    def __init__(self, seconds: float, interval: int, count_max: int):
        super().__init__(f"no answer for {seconds:.0f} s")
        self.seconds, self.interval, self.count_max = seconds, interval, count_max


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
