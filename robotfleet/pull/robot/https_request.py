"""One HTTPS request on its own connection, for the agent's idle probe
(robotfleet/pull/robot/probe.py), without http.client (its import, with
the email package's, was a fifth of an idle check's CPU): HTTP/1.1,
``Connection: close``, an answer's body by its Content-Length, chunked, or
up to the end, never more than a cap.  The server's certificate is checked
against ``ca`` (a file), else the system's CAs, looked up by hash as the
handshake needs one (loading the whole bundle was another tenth).  TLS 1.3
only: its ClientHello is ~300 bytes shorter; a server without it fails here,
and the caller's fallback (git, which takes TLS 1.2) reads the branch.  The
bytes each way are the kernel's count for the connection, TLS included.

TLS is `_ssl`'s, the C module `ssl` wraps, with the same checks (a context
for PROTOCOL_TLS_CLIENT: the certificate against the CAs and the host
name, by OpenSSL): importing `ssl` (its enums, built at import, and what
it imports: socket, base64, re) costs ~23 ms of CPU against ~4 ms for
`_ssl` and `_socket`, and a str host name goes through the IDNA codec;
together a quarter of an idle check.  Where `_ssl` does not offer what
this uses (another Python), the request fails and git's fetch reads the
branch."""

from __future__ import annotations

import _socket
import _ssl
import os
import struct

SSLError = _ssl.SSLError  # what `ssl` raises as ssl.SSLError: the same class

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


def context(ca: str | None):
    """A client context (`_ssl`'s) that checks the certificate and the host
    name, TLS 1.3 only; its CAs from ``ca``, else the system's, as
    ssl.get_default_verify_paths finds them (SSL_CERT_FILE, SSL_CERT_DIR)."""
    made = _ssl._SSLContext(_ssl.PROTOCOL_TLS_CLIENT)
    made.minimum_version = _ssl.PROTO_TLSv1_3
    if ca:
        made.load_verify_locations(cafile=ca)
        return made
    file_env, file, dir_env, directory = _ssl.get_default_verify_paths()
    file, directory = os.environ.get(file_env, file), os.environ.get(dir_env, directory)
    if directory and os.path.isdir(directory):
        made.load_verify_locations(capath=directory)
    elif file and os.path.isfile(file):
        made.load_verify_locations(cafile=file)
    return made


def request(host: str, port: int, head: bytes, body: bytes, ca: str | None, timeout: float, limit: int) -> Answer:
    """Send ``head`` (the request line and headers, without the blank line
    that ends them) and ``body``; the answer, its body at most ``limit``
    bytes (Failed beyond).  OSError, SSLError, Failed."""
    raw = _connect(host, port, timeout)
    try:
        tls = _tls(raw, host, ca)
        data = memoryview(head + b"Connection: close\r\n\r\n" + body)
        while data:
            data = data[tls.write(data) :]
        answer = _read(_Reader(tls), limit)
        answer.sent, answer.received = _tcp_bytes(raw)
        return answer
    finally:
        raw.close()


class _Socket(_socket.socket):
    """`_socket`'s socket, with the weak reference `_ssl` keeps to it."""

    __slots__ = ("__weakref__",)


def _connect(host: str, port: int, timeout: float):
    """socket.create_connection with `_socket`'s socket, which `_ssl` takes
    whatever patched the `socket` module (gevent's, in a pyinfra process),
    and an ASCII name as bytes (a str goes through the IDNA codec)."""
    error = None
    for family, kind, proto, _, address in _socket.getaddrinfo(
        host.encode() if host.isascii() else host, port, 0, _socket.SOCK_STREAM
    ):
        sock = _Socket(family, kind, proto)
        try:
            sock.settimeout(timeout)
            sock.connect(address)
            return sock
        except OSError as failed:
            sock.close()
            error = failed
    raise error or Failed(f"{host}: no address")


def _tls(raw, host: str, ca: str | None):
    """`_ssl`'s TLS connection over ``raw`` (read, write), its handshake
    done; Failed where this Python's `_ssl` differs from what this uses
    (the probe then leaves the check to git, as for any failure)."""
    name = host if host.isascii() else host.encode("idna").decode("ascii")
    try:
        made = context(ca)._wrap_socket(raw, False, name)
    except (AttributeError, TypeError) as error:
        raise Failed(f"this Python's _ssl cannot make the request: {error}") from None
    made.do_handshake()
    return made


class _Reader:
    def __init__(self, sock):
        self.sock, self.buffer, self.ended = sock, b"", False

    def fill(self) -> bool:
        if self.ended:
            return False
        try:
            data = self.sock.read(65536)
        except (_ssl.SSLZeroReturnError, _ssl.SSLEOFError):  # closed, with or without TLS's close_notify
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
        info = sock.getsockopt(_socket.IPPROTO_TCP, _socket.TCP_INFO, _TCP_INFO_AT + _TCP_INFO_BYTES.size)
        return _TCP_INFO_BYTES.unpack_from(info, _TCP_INFO_AT)
    except (OSError, struct.error, AttributeError):
        return 0, 0
