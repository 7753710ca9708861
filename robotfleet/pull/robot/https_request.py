"""One HTTPS request on its own connection, for the agent's idle probe
(robotfleet/pull/robot/probe.py), without http.client (its import, with
the email package's, was a fifth of an idle check's CPU): HTTP/1.1,
``Connection: close``, an answer's body by its Content-Length, chunked, or
up to the end, never more than a cap.  The server's certificate is checked
against ``ca`` (a file), else the system's CAs, looked up by hash as the
handshake needs one (loading the whole bundle was another tenth).  TLS 1.3
only: its ClientHello is ~300 bytes shorter; a server without it fails here,
and the caller's fallback (git, which takes TLS 1.2) reads the branch.  The
bytes each way are the kernel's count for the connection, TLS included."""

from __future__ import annotations

import socket
import ssl
import struct

HEAD_MAX = 16384
_TCP_INFO_BYTES = struct.Struct("=QQ")  # tcpi_bytes_acked, tcpi_bytes_received (Linux >= 4.1)
_TCP_INFO_AT = 120


class Failed(OSError):
    """The exchange did not give an HTTP answer (one line)."""


class Answer:
    """An HTTP answer (a plain class: the idle check imports no dataclasses)."""

    def __init__(self, status: int, headers: dict | None = None, body: bytes = b""):
        self.status, self.body = status, body
        self.headers = headers if headers is not None else {}  # lower-case name -> value
        self.sent = self.received = 0


def context(ca: str | None) -> ssl.SSLContext:
    made = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)  # hostname and certificate checked
    made.minimum_version = ssl.TLSVersion.TLSv1_3
    if ca:
        made.load_verify_locations(cafile=ca)
    else:
        paths = ssl.get_default_verify_paths()
        if paths.capath:
            made.load_verify_locations(capath=paths.capath)
        if paths.cafile and not paths.capath:
            made.load_verify_locations(cafile=paths.cafile)
    return made


def request(host: str, port: int, head: bytes, body: bytes, ca: str | None, timeout: float, limit: int) -> Answer:
    """Send ``head`` (the request line and headers, without the blank line
    that ends them) and ``body``; the answer, its body at most ``limit``
    bytes (Failed beyond).  OSError, ssl.SSLError, Failed."""
    raw = socket.create_connection((host, port), timeout=timeout)
    try:
        with context(ca).wrap_socket(raw, server_hostname=host) as tls:
            tls.sendall(head + b"Connection: close\r\n\r\n" + body)
            answer = _read(_Reader(tls), limit)
            answer.sent, answer.received = _tcp_bytes(tls)
            return answer
    finally:
        raw.close()


class _Reader:
    def __init__(self, sock):
        self.sock, self.buffer, self.ended = sock, b"", False

    def fill(self) -> bool:
        if self.ended:
            return False
        try:
            data = self.sock.recv(65536)
        except ssl.SSLZeroReturnError:
            data = b""
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


def _tcp_bytes(sock) -> tuple[int, int]:
    """(bytes sent, bytes received) on the connection, as the kernel counts
    them; (0, 0) where it does not."""
    try:
        info = sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_INFO, _TCP_INFO_AT + _TCP_INFO_BYTES.size)
        return _TCP_INFO_BYTES.unpack_from(info, _TCP_INFO_AT)
    except (OSError, struct.error, AttributeError):
        return 0, 0
