"""What a wake's exchanges with the fleet remote cost (robotfleet/pull/robot/transport.py
makes them): bytes each way, requests and seconds, per exchange and in all.
Over SSH, ssh's own count from its log (read by
robotfleet/pull/robot/remote_git.py), each ssh session one request; over
HTTPS, git's own trace of its HTTP exchanges (GIT_TRACE_CURL, read as it
streams)."""

from __future__ import annotations

import re
import threading
from dataclasses import dataclass, field

# git's trace of curl (http.c): "=> Send header, 0000000247 bytes (0xf7)"
_CURL = re.compile(rb"^\S+ \S+:\d+ +(=>|<=) (?:Send|Recv) (header|data), (\d+) bytes")
_TRACE = re.compile(rb"^\d\d:\d\d:\d\d\.\d+ \S+:\d+ ")


@dataclass
class Cost:
    """What the exchanges of one wake cost: bytes over the network and time."""

    sent: int = 0
    received: int = 0
    seconds: float = 0.0
    requests: int = 0
    exchanges: list = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock, repr=False, compare=False)

    def add(self, what: str, sent: int, received: int, seconds: float, requests: int = 1) -> None:
        with self.lock:  # the shards' fetches run in threads
            self.sent += sent
            self.received += received
            self.seconds += seconds
            self.requests += requests
            self.exchanges.append(
                {"what": what, "sent": sent, "received": received, "seconds": round(seconds, 3), "requests": requests}
            )

    def as_dict(self) -> dict:
        return {
            "sent": self.sent,
            "received": self.received,
            "seconds": round(self.seconds, 3),
            "requests": self.requests,
            "exchanges": self.exchanges,
        }


class CurlTrace:
    """git's stderr with GIT_TRACE_CURL=2, read as it streams (a fetch's
    trace is several times its size): the HTTP bytes each way, the requests,
    and git's own lines (its complaint, if any) apart."""

    def __init__(self):
        self.sent = self.received = self.requests = 0
        self.said: list[bytes] = []

    def line(self, line: bytes) -> None:
        match = _CURL.match(line)
        if match:
            size = int(match.group(3))
            if match.group(1) == b"=>":
                self.sent += size
                self.requests += match.group(2) == b"header"
            else:
                self.received += size
        elif not _TRACE.match(line) and len(self.said) < 200:
            self.said.append(line)

    def read(self, stream) -> None:
        for line in stream:
            self.line(line)

    @property
    def stderr(self) -> bytes:
        return b"".join(self.said)
