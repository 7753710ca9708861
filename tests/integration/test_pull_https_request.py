"""The idle probe's one HTTPS request (robotfleet/pull/robot/https_request.py)
against a real TLS server on 127.0.0.1 that answers what each test scripts:
a chunked answer read whole, and a hostile or broken peer (an answer too
long, a head without end, no HTTP, a server without TLS 1.3, a certificate
from another CA) refused with one exception, never read without bound;
a server that stalls or trickles given up in bound."""

from __future__ import annotations

import socket
import ssl
import time

import pytest

from robotfleet.pull.robot import https_request, probe
from tests.integration import httpsgit
from tests.integration.httpsgit import Scripted
from tests.lab.linkproxy import Link

HEAD = b"GET /fleet.git/info/refs HTTP/1.1\r\nHost: 127.0.0.1\r\n"


@pytest.fixture(scope="module")
def tls(tmp_path_factory):
    return httpsgit.make_ca(tmp_path_factory.mktemp("tls"))


def ask(server, ca, limit=1000):
    return https_request.request("127.0.0.1", server.port, HEAD, b"", str(ca), 10, limit)


def test_a_chunked_answer_is_read_whole_and_its_bytes_counted(tls):
    server = Scripted(
        tls,
        b'HTTP/1.1 200 OK\r\nTransfer-Encoding: chunked\r\nETag: "a"\r\n\r\n5\r\nhello\r\n6;x=y\r\n world\r\n0\r\n\r\n',
    )
    try:
        answer = ask(server, tls[0])
        assert (answer.status, answer.body, answer.headers["etag"]) == (200, b"hello world", '"a"')
        assert answer.sent > len(HEAD) and answer.received > 100
        assert server.requests[0].startswith(HEAD) and b"Connection: close\r\n" in server.requests[0]
    finally:
        server.close()


@pytest.mark.parametrize(
    "answer, said",
    [
        (b"HTTP/1.1 200 OK\r\nContent-Length: 5000\r\n\r\n" + b"x" * 5000, "larger than 1000 bytes"),
        (
            b"HTTP/1.1 200 OK\r\nTransfer-Encoding: chunked\r\n\r\n800\r\n" + b"x" * 2048 + b"\r\n0\r\n\r\n",
            "larger than 1000 bytes",
        ),
        (b"HTTP/1.1 200 OK\r\n\r\n" + b"x" * 5000, "larger than 1000 bytes"),
        (b"HTTP/1.1 200 OK\r\nTransfer-Encoding: chunked\r\n\r\nzz\r\n", "not a chunk's size"),
        (b"HTTP/1.1 200 OK\r\nX: " + b"y" * 20000, "did not end"),
        (b"SSH-2.0-OpenSSH_9.2\r\n\r\n", "not an HTTP answer"),
        (b"HTTP/1.1 200 OK\r\nContent-Length: 50\r\n\r\nshort", "ended early"),
    ],
)
def test_a_broken_or_hostile_answer_is_one_failure(tls, answer, said):
    server = Scripted(tls, answer)
    try:
        with pytest.raises(https_request.Failed, match=said):
            ask(server, tls[0])
    finally:
        server.close()


def test_no_tls_1_3_or_another_ca_is_refused_and_the_probe_leaves_it_to_git(tls, tmp_path):
    old = Scripted(tls, b"HTTP/1.1 304 Not Modified\r\n\r\n", tls12_only=True)
    other = httpsgit.make_ca(tmp_path / "other")[0]
    good = Scripted(tls, b"HTTP/1.1 304 Not Modified\r\n\r\n")
    try:
        with pytest.raises(ssl.SSLError):
            ask(old, tls[0])
        with pytest.raises(ssl.SSLCertVerificationError):
            ask(good, other)
        assert ask(good, tls[0]).status == 304
        memo = {"kind": "static", "commit": "a" * 40, "validators": {"etag": '"a"'}}
        url = f"https://127.0.0.1:{old.port}/fleet.git"
        assert probe.https(url, "robotfleet/releases", memo, str(tls[0]), 10).commit is None  # a full fetch follows
        url = f"https://127.0.0.1:{good.port}/fleet.git"
        assert probe.https(url, "robotfleet/releases", memo, str(other), 10).commit is None
        assert probe.https(url, "robotfleet/releases", memo, str(tls[0]), 10).commit == "a" * 40
        assert b'If-None-Match: "a"\r\n' in good.requests[-1]
    finally:
        old.close()
        good.close()


def test_the_certificate_s_names_are_checked(tls):
    """The context checks the host name: the certificate names 127.0.0.1
    and localhost, nothing else."""
    server = Scripted(tls, b"HTTP/1.1 304 Not Modified\r\n\r\n")
    try:
        for name, good in (("127.0.0.1", True), ("localhost", True), ("robot.example", False), ("127.0.0.2", False)):
            with socket.create_connection(("127.0.0.1", server.port), timeout=10) as raw:
                conn = https_request._Tls(raw, https_request.context(str(tls[0])), name, time.monotonic() + 10, 10)
                if good:
                    conn.call(conn.tls.do_handshake)
                    conn.call(conn.tls.write, HEAD + b"\r\n")
                    assert conn.read().startswith(b"HTTP/1.1 304")
                else:
                    with pytest.raises(ssl.SSLCertVerificationError, match="mismatch"):
                        conn.call(conn.tls.do_handshake)
    finally:
        server.close()


def test_a_server_that_stalls_or_trickles_is_given_up_in_bound(tls):
    """A server that accepts and then sends nothing (a frozen link before it)
    is given up after ``silent`` seconds; one that trickles a byte at a time
    after the whole request's ``timeout``.  Before: each read waited up to
    the timeout, so a trickle held the robot's check for ever."""
    server = Scripted(tls, b"HTTP/1.1 304 Not Modified\r\n\r\n")
    slow = Scripted(tls, b"HTTP/1.1 200 OK\r\nContent-Length: 100\r\n\r\n" + b"x" * 100, pace=0.2)
    try:
        with Link(server.port) as link:
            link.freeze()
            began = time.monotonic()
            with pytest.raises(TimeoutError):
                https_request.request("127.0.0.1", link.port, HEAD, b"", str(tls[0]), 30, 1000, silent=1)
            assert time.monotonic() - began < 5
        began = time.monotonic()
        with pytest.raises(TimeoutError):
            https_request.request("127.0.0.1", slow.port, HEAD, b"", str(tls[0]), 3, 1000, silent=1)
        assert time.monotonic() - began < 6
    finally:
        server.close()
        slow.close()
