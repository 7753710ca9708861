"""One HTTPS request on its own connection, for the agent's probe
(robotfleet/pull/robot/probe.py), its bytes counted with TLS: HTTP/1.1,
``Connection: close``, an answer's body by its Content-Length, chunked, or
up to the end, never more than a cap.  TLS is the ``ssl`` module's
(PROTOCOL_TLS_CLIENT: the certificate against ``ca``, a file, else the
system's CAs, looked up by hash as the handshake needs one, and the host
name, checked by OpenSSL), TLS 1.3 only: its
ClientHello is ~300 bytes shorter; a server without it fails here, and
the caller's fallback (git, which takes TLS 1.2) reads the branch.

Bounded as the agent's other exchanges are: the whole request within
``timeout`` (pull_fetch_timeout), and a server that accepts, then stalls or
trickles, given up once it has sent nothing for ``silent`` seconds (the
silence the host's SSH keepalives allow).  The TLS records go through
memory (ssl.MemoryBIO), so the bytes each way, TLS included, are counted
as they pass."""

from __future__ import annotations

import socket
import ssl
import time

HEAD_MAX = 16384
CHUNK = 65536


class Failed(OSError):
    """The exchange did not give an HTTP answer (one line)."""


class Answer:
    """An HTTP answer."""

    def __init__(self, status: int, headers: dict | None = None, body: bytes = b""):
        self.status, self.body = status, body
        self.headers = headers if headers is not None else {}  # lower-case name -> value
        self.sent = self.received = 0


def context(ca: str | None) -> ssl.SSLContext:
    made = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)  # host name and certificate checked
    made.minimum_version = ssl.TLSVersion.TLSv1_3
    if ca:
        made.load_verify_locations(cafile=ca)
        return made
    paths = ssl.get_default_verify_paths()  # the directory's CAs are looked up by hash as the handshake needs one
    if paths.capath:
        made.load_verify_locations(capath=paths.capath)
    elif paths.cafile:
        made.load_verify_locations(cafile=paths.cafile)
    return made


def request(
    host: str, port: int, head: bytes, body: bytes, ca: str | None, timeout: float, limit: int, silent: float = 60
) -> Answer:
    """Send ``head`` (the request line and headers, without the blank line
    that ends them) and ``body``; the answer, its body at most ``limit``
    bytes (Failed beyond).  OSError (TimeoutError past a bound), ssl.SSLError, Failed."""
    deadline = time.monotonic() + timeout
    with socket.create_connection((host, port), timeout=min(timeout, silent)) as raw:
        tls = _Tls(raw, context(ca), host, deadline, silent)
        tls.call(tls.tls.do_handshake)
        tls.call(tls.tls.write, head + b"Connection: close\r\n\r\n" + body)
        answer = _read(_Reader(tls), limit)
        answer.sent, answer.received = tls.sent, tls.received
        return answer


class _Tls:
    """TLS over ``raw`` through memory: each record read or written counted,
    each wait on the socket bounded by the deadline and the silence."""

    def __init__(self, raw: socket.socket, made: ssl.SSLContext, host: str, deadline: float, silent: float):
        self.raw, self.deadline, self.silent = raw, deadline, silent
        self.incoming, self.outgoing = ssl.MemoryBIO(), ssl.MemoryBIO()
        self.tls = made.wrap_bio(self.incoming, self.outgoing, server_hostname=host)
        self.sent = self.received = 0

    def call(self, operation, *args):
        """``operation`` of the TLS object, fed from the socket until it can answer."""
        while True:
            try:
                result = operation(*args)
            except ssl.SSLWantReadError:
                self._flush()
                self._fill()
                continue
            self._flush()
            return result

    def read(self) -> bytes:
        """Some of the answer; b"" at its end (with or without TLS's close_notify)."""
        try:
            return self.call(self.tls.read, CHUNK)
        except (ssl.SSLZeroReturnError, ssl.SSLEOFError):
            return b""

    def _wait(self) -> None:
        left = self.deadline - time.monotonic()
        if left <= 0:
            raise TimeoutError("the server did not answer in time")
        self.raw.settimeout(min(left, self.silent))

    def _flush(self) -> None:
        data = self.outgoing.read()
        if data:
            self._wait()
            self.raw.sendall(data)
            self.sent += len(data)

    def _fill(self) -> None:
        self._wait()
        data = self.raw.recv(CHUNK)
        if data:
            self.received += len(data)
            self.incoming.write(data)
        else:
            self.incoming.write_eof()


class _Reader:
    def __init__(self, tls: _Tls):
        self.tls, self.buffer, self.ended = tls, b"", False

    def fill(self) -> bool:
        if self.ended:
            return False
        data = self.tls.read()
        self.ended = not data
        self.buffer += data
        return bool(data)

    def until(self, mark: bytes, cap: int) -> bytes:
        while mark not in self.buffer:
            if len(self.buffer) > cap or not self.fill():
                raise Failed("the answer's head or a chunk's size line did not end")
        found, _, self.buffer = self.buffer.partition(mark)
        return found

    def take(self, size: int) -> bytes:
        while len(self.buffer) < size:
            if not self.fill():
                raise Failed("the answer ended early")
        found, self.buffer = self.buffer[:size], self.buffer[size:]
        return found


def _read(reader: _Reader, limit: int) -> Answer:
    lines = reader.until(b"\r\n\r\n", HEAD_MAX).decode("latin-1").split("\r\n")
    words = lines[0].split(" ", 2)
    if len(words) < 2 or not words[0].startswith("HTTP/1.") or not words[1].isdigit():
        raise Failed(f"not an HTTP answer: {lines[0][:80]!r}")
    headers = {}
    for line in lines[1:]:
        name, _, value = line.partition(":")
        headers[name.strip().lower()] = value.strip()
    answer = Answer(int(words[1]), headers)
    if answer.status in (204, 304) or 100 <= answer.status < 200:
        return answer
    if "chunked" in headers.get("transfer-encoding", "").lower():
        parts, size = [], 0
        while (chunk := _chunk_size(reader.until(b"\r\n", 1024))) > 0:
            size += chunk
            if size > limit:
                raise Failed(f"an answer larger than {limit} bytes")
            parts.append(reader.take(chunk))
            reader.take(2)
        answer.body = b"".join(parts)
    elif headers.get("content-length", "").isdigit():
        if int(headers["content-length"]) > limit:
            raise Failed(f"an answer larger than {limit} bytes")
        answer.body = reader.take(int(headers["content-length"]))
    else:
        while len(reader.buffer) <= limit and reader.fill():
            pass
        if len(reader.buffer) > limit:
            raise Failed(f"an answer larger than {limit} bytes")
        answer.body = reader.buffer
    return answer


def _chunk_size(line: bytes) -> int:
    try:
        return int(line.split(b";")[0].strip(), 16)
    except ValueError:
        raise Failed(f"not a chunk's size: {line[:40]!r}") from None
