"""A git remote over HTTPS on 127.0.0.1 for tests: git's own
``git http-backend`` (smart HTTP, protocol v2) or the bare repository's
files as they are (a static, "dumb" remote), behind TLS with a certificate
from a private CA made here with openssl.  Counts the requests it answers.
Also a scripted TLS server (``Scripted``) that answers each connection with
given bytes, for the idle probe's own HTTPS request.

Each server runs in a child process of its own (``python -m
tests.integration.httpsgit``): the idle probe's TLS is `_ssl`'s over
`_socket` (robotfleet/pull/robot/https_request.py), whose blocking reads
hold the whole of a gevent-patched test process, where a server thread is a
greenlet that would never run."""

from __future__ import annotations

import http.server
import os
import shutil
import socket
import ssl
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def make_ca(where: Path, address: str = "127.0.0.1") -> tuple[Path, Path, Path]:
    """(CA certificate, server certificate, server key) for ``address`` (an IP address)."""
    where.mkdir(parents=True, exist_ok=True)

    def openssl(*args: str) -> None:
        subprocess.run(["openssl", *args], check=True, capture_output=True, cwd=where)

    openssl(
        "req",
        "-x509",
        "-newkey",
        "ec",
        "-pkeyopt",
        "ec_paramgen_curve:P-256",
        "-nodes",
        "-days",
        "2",
        "-subj",
        "/CN=fleet test CA",
        "-keyout",
        "ca.key",
        "-out",
        "ca.pem",
    )
    openssl(
        "req",
        "-newkey",
        "ec",
        "-pkeyopt",
        "ec_paramgen_curve:P-256",
        "-nodes",
        "-subj",
        f"/CN={address}",
        "-keyout",
        "server.key",
        "-out",
        "server.csr",
    )
    (where / "ext").write_text(f"subjectAltName=IP:{address},DNS:localhost\n")
    openssl(
        "x509",
        "-req",
        "-in",
        "server.csr",
        "-CA",
        "ca.pem",
        "-CAkey",
        "ca.key",
        "-CAcreateserial",
        "-days",
        "2",
        "-extfile",
        "ext",
        "-out",
        "server.pem",
    )
    return where / "ca.pem", where / "server.pem", where / "server.key"


class _Child:
    """A server of this module running in a child process; ``work`` holds
    what it records (each request)."""

    def __init__(self, *args: str, files: dict[str, bytes] | None = None):
        """``args``: the server's (``__main__`` below); ``files``: put in ``work`` first, for it to read."""
        self.work = Path(tempfile.mkdtemp(prefix="httpsgit-"))
        for name, data in (files or {}).items():
            (self.work / name).write_bytes(data)
        self.process = subprocess.Popen(
            [sys.executable, "-m", "tests.integration.httpsgit", str(self.work), *args],
            cwd=ROOT,
            stdout=subprocess.PIPE,
            text=True,
        )
        line = self.process.stdout.readline()
        if not line.strip().isdigit():
            self.process.kill()
            raise RuntimeError(f"the test HTTPS server did not start ({self.process.wait()})")
        self.port = int(line)

    def close(self) -> None:
        self.process.terminate()
        self.process.wait()
        self.process.stdout.close()
        shutil.rmtree(self.work, ignore_errors=True)


class Server(_Child):
    """``root`` (a directory of bare repositories) at https://HOST:PORT/
    (127.0.0.1 and a free port unless given: an end-to-end test serves the
    lab's robots on its docker network's gateway address)."""

    def __init__(
        self,
        root: Path,
        cert: Path,
        key: Path,
        smart: bool = True,
        host: str = "127.0.0.1",
        port: int = 0,
        tickets: int | None = None,
    ):
        """``tickets``: the TLS 1.3 session tickets it sends a client (OpenSSL's default: 2)."""
        self.smart, self.host = smart, host
        kind = "smart" if smart else "static"
        more = () if tickets is None else (str(tickets),)
        super().__init__("git", str(root), str(cert), str(key), kind, host, str(port), *more)

    @property
    def requests(self) -> int:
        """How many requests it has answered."""
        return len(list(self.work.glob("*.request")))

    def url(self, name: str) -> str:
        return f"https://{self.host}:{self.port}/{name}"


class Scripted(_Child):
    """A TLS server on 127.0.0.1 answering each connection with ``answer``
    (bytes, sent after the request's head); TLS 1.2 at most if asked."""

    def __init__(self, tls, answer: bytes, tls12_only: bool = False, pace: float = 0.0):
        """``pace``: seconds between the answer's bytes (a server that trickles)."""
        ca, cert, key = tls
        files = {"answer": answer, "pace": str(pace).encode()}
        super().__init__("scripted", str(cert), str(key), "tls12" if tls12_only else "tls13", files=files)

    @property
    def requests(self) -> list[bytes]:
        """Each request's head, in order."""
        return [path.read_bytes() for path in sorted(self.work.glob("*.request"), key=lambda p: int(p.stem))]


class _Recorder:
    """The child's side: each request written to ``work``/N.request."""

    def __init__(self, work: Path):
        self.work, self.count, self.lock = work, 0, threading.Lock()

    def record(self, data: bytes) -> None:
        with self.lock:
            self.count += 1
            number = self.count
        (self.work / f"{number}.tmp").write_bytes(data)
        os.replace(self.work / f"{number}.tmp", self.work / f"{number}.request")


def _serve_git(
    recorder: _Recorder, root: str, cert: str, key: str, kind: str, host: str, port: str, tickets: str = ""
) -> None:
    smart = kind == "smart"

    class Handler(http.server.SimpleHTTPRequestHandler):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, directory=root, **kwargs)

        def log_message(self, *args):
            pass

        def do_GET(self):
            recorder.record(self.requestline.encode())
            if smart:
                self.backend()
            else:
                super().do_GET()

        def do_POST(self):
            recorder.record(self.requestline.encode())
            if smart:
                self.backend()
            else:
                self.send_error(405)

        def backend(self):
            path, _, query = self.path.partition("?")
            length = int(self.headers.get("Content-Length") or 0)
            body = self.rfile.read(length) if length else b""
            env = {
                "PATH": os.environ["PATH"],
                "GIT_PROJECT_ROOT": root,
                "GIT_HTTP_EXPORT_ALL": "1",
                "PATH_INFO": path,
                "QUERY_STRING": query,
                "REQUEST_METHOD": self.command,
                "CONTENT_TYPE": self.headers.get("Content-Type") or "",
                "CONTENT_LENGTH": str(len(body)),
                "REMOTE_ADDR": "127.0.0.1",
                "REMOTE_USER": "robot",
            }
            for header, name in (("Git-Protocol", "GIT_PROTOCOL"), ("Content-Encoding", "HTTP_CONTENT_ENCODING")):
                if self.headers.get(header):
                    env[name] = self.headers[header]
            done = subprocess.run(
                [shutil.which("git") or "git", "http-backend"], input=body, env=env, capture_output=True
            )
            head, _, content = done.stdout.partition(b"\r\n\r\n")
            status, headers = 200, []
            for line in head.decode("latin-1").split("\r\n"):
                name, _, value = line.partition(": ")
                if name.lower() == "status":
                    status = int(value.split()[0])
                elif name:
                    headers.append((name, value))
            self.send_response(status)
            for name, value in headers:
                self.send_header(name, value)
            self.send_header("Content-Length", str(len(content)))
            self.end_headers()
            self.wfile.write(content)

    httpd = http.server.ThreadingHTTPServer((host, int(port)), Handler)
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    context.load_cert_chain(cert, key)
    if tickets:
        context.num_tickets = int(tickets)
    httpd.socket = context.wrap_socket(httpd.socket, server_side=True)
    print(httpd.server_address[1], flush=True)
    httpd.serve_forever()


def _serve_scripted(recorder: _Recorder, cert: str, key: str, version: str) -> None:
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    context.load_cert_chain(cert, key)
    if version == "tls12":
        context.maximum_version = ssl.TLSVersion.TLSv1_2
    answer = (recorder.work / "answer").read_bytes()
    pace = float((recorder.work / "pace").read_text())
    listener = socket.create_server(("127.0.0.1", 0))
    print(listener.getsockname()[1], flush=True)
    while True:
        raw, _ = listener.accept()
        try:
            with context.wrap_socket(raw, server_side=True) as conn:
                data = b""
                while b"\r\n\r\n" not in data and (chunk := conn.recv(4096)):
                    data += chunk
                recorder.record(data)
                for at in range(0, len(answer), 1 if pace else len(answer) or 1):
                    time.sleep(pace)
                    conn.sendall(answer[at : at + 1] if pace else answer)
        except (OSError, ssl.SSLError):
            pass


if __name__ == "__main__":
    work, kind, *rest = sys.argv[1:]
    serve = {"git": _serve_git, "scripted": _serve_scripted}[kind]
    serve(_Recorder(Path(work)), *rest)
