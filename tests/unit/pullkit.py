"""What the pull-mode tests share: real keys, a real TUF repository on disk
with a release in it, a robot's trust state, and small servers (static
HTTP for a repository, an OCI registry answering the manifest requests the
payload role's registry client makes).

Modules that import ssl (python-tuf through urllib3) are imported when a
test runs, not at collection (tests/unit/conftest.py says why)."""

from __future__ import annotations

import contextlib
import datetime
import functools
import hashlib
import http.server
import importlib
import json
import os
import threading
from pathlib import Path

import pytest

NOW = datetime.datetime.now(datetime.timezone.utc).replace(microsecond=0)
DAY = datetime.timedelta(days=1)


def module(name: str):
    return importlib.import_module(f"robotfleet.pull.{name}")


class Fleet:
    """Keys, a repository and one robot's trust state under ``base``."""

    def __init__(self, base: Path, now: datetime.datetime = NOW, name: str = "keys"):
        self.base = base
        self.keys = module("operator.keys").KeyDir(base / name)
        self.keys.generate("root")
        self.keys.generate("online")
        self.repository = module("operator.repository").Repository(base / "repo")
        self.expiry = module("operator.repository").Expiry()
        self.repository.create(self.keys.signer("root"), self.keys.signer("online"), self.expiry, now)
        self.state = base / "robot"

    def release(
        self,
        version: int,
        now: datetime.datetime = NOW,
        code: bytes | None = None,
        expiry=None,
        robots=("robot1", "robot2"),
        record_expires: datetime.datetime | None = None,
    ):
        """Publish release ``version`` (its code archive: ``code``); the record."""
        record, waves = module("protocol.record"), module("protocol.waves")
        expiry = expiry or self.expiry
        commit = hashlib.sha1(f"commit {version}".encode()).hexdigest()
        built = record.build(
            version,
            now,
            record_expires or now + expiry.targets,
            commit,
            "b" * 64,
            "inventories/robots.yaml",
            "c" * 64,
            list(robots),
            {r: {"reg.lan/ros/payload:1": "sha256:" + "d" * 64} for r in robots},
            {},
            waves.Plan(),
        )
        archive = self.base / f"code-{version}.tar.gz"
        archive.write_bytes(code if code is not None else f"code of release {version}".encode())
        self.repository.publish(built, {built.code: archive}, self.keys.signer("online"), expiry, now)
        return built

    def trust(self, trusted_time: datetime.datetime | None = None) -> None:
        module("robot.verify").initialize(
            self.state, (self.repository.metadata / "root.json").read_bytes(), trusted_time
        )

    def client(self, clock=None, source=None):
        trust = module("robot.verify")
        return trust.Client(self.state, str(source or self.repository.path), clock=clock or (lambda: NOW))

    def refresh(self, clock=None, source=None, applied: int = 0):
        return self.client(clock, source).refresh(applied)


def tree_state(path: Path) -> dict:
    """Every file and link under ``path`` (links followed at the top) -> its bytes or target."""
    found = {}
    for directory, dirs, files in os.walk(path, followlinks=False):
        for name in dirs + files:
            full = Path(directory, name)
            key = str(full.relative_to(path))
            if full.is_symlink():
                found[key] = ("link", os.readlink(full), Path(full).resolve().name)
            elif full.is_file():
                found[key] = full.read_bytes()
    tuf = path / "tuf"
    if tuf.is_symlink():
        found.update({f"tuf->{k}": v for k, v in tree_state(tuf.resolve()).items()})
    return found


def refused(fleet, reason: str, **kwargs) -> str:
    """Refresh, expecting a refusal for ``reason``, and the trusted state untouched; its line."""
    before = tree_state(fleet.state)
    with pytest.raises(module("robot.refusals").Refused) as caught:
        fleet.refresh(**kwargs)
    assert caught.value.reason == reason, caught.value.line
    assert "\n" not in caught.value.line
    assert tree_state(fleet.state) == before
    return caught.value.line


def edit_json(path: Path, change) -> None:
    """Rewrite the JSON file ``path`` with ``change(data)`` applied (no re-signing)."""
    data = json.loads(path.read_bytes())
    change(data)
    path.write_text(json.dumps(data, indent=1))


@contextlib.contextmanager
def static_http(directory: Path):
    """A plain HTTP server for ``directory`` on 127.0.0.1; yields its base URL."""
    handler = functools.partial(_Quiet, directory=str(directory))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}"
    finally:
        server.shutdown()
        server.server_close()


class _Quiet(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args):
        pass


OCI_INDEX = "application/vnd.oci.image.index.v1+json"


class Registry:
    """An OCI distribution registry's manifest endpoints, as the spec has
    them: GET and HEAD /v2/<name>/manifests/<tag or digest>, with
    Content-Type and Docker-Content-Digest, a MANIFEST_UNKNOWN error body
    (404) otherwise, and /v2/ answering 200.  ``tag(name, tag, manifest)``
    pushes a manifest (bytes); its digest is returned."""

    def __init__(self):
        self.manifests: dict[tuple[str, str], tuple[str, bytes]] = {}
        self.requests: list[tuple[str, str]] = []
        registry = self

        class Handler(http.server.BaseHTTPRequestHandler):
            def log_message(self, *args):
                pass

            def do_HEAD(self):
                self._answer(head=True)

            def do_GET(self):
                self._answer(head=False)

            def _answer(self, head: bool):
                registry.requests.append((self.command, self.path))
                if self.path == "/v2/":
                    return self._send(200, "application/json", b"{}", head)
                parts = self.path.split("/manifests/")
                found = registry.manifests.get((parts[0][len("/v2/") :], parts[1])) if len(parts) == 2 else None
                if found is None:
                    body = json.dumps({"errors": [{"code": "MANIFEST_UNKNOWN", "message": "manifest unknown"}]})
                    return self._send(404, "application/json", body.encode(), head)
                media_type, body = found
                self._send(200, media_type, body, head, digest="sha256:" + hashlib.sha256(body).hexdigest())

            def _send(self, code, media_type, body, head, digest=None):
                self.send_response(code)
                self.send_header("Content-Type", media_type)
                self.send_header("Content-Length", str(len(body)))
                if digest:
                    self.send_header("Docker-Content-Digest", digest)
                self.end_headers()
                if not head:
                    self.wfile.write(body)

        self.server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.address = f"127.0.0.1:{self.server.server_address[1]}"
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    def tag(self, name: str, tag: str, layers: str = "x") -> str:
        body = json.dumps(
            {
                "schemaVersion": 2,
                "mediaType": OCI_INDEX,
                "manifests": [
                    {
                        "mediaType": "application/vnd.oci.image.manifest.v1+json",
                        "size": 1,
                        "platform": {"os": "linux", "architecture": "amd64"},
                        "digest": "sha256:" + hashlib.sha256(layers.encode()).hexdigest(),
                    }
                ],
            }
        ).encode()
        digest = "sha256:" + hashlib.sha256(body).hexdigest()
        self.manifests[(name, tag)] = self.manifests[(name, digest)] = (OCI_INDEX, body)
        return digest

    def close(self):
        self.server.shutdown()
        self.server.server_close()


class Flood:
    """A hostile mirror: ``directory`` served over plain HTTP on 127.0.0.1,
    but ``path`` answers ``size`` bytes with no length announced (it ends
    when the connection does); ``sent``: how many of them the client took
    before closing.  A context manager; ``url``: the base URL."""

    def __init__(self, directory: Path, path: str, size: int = 64 << 20):
        self.sent = 0
        flood = self

        class Handler(_Quiet):
            def do_GET(self):
                if self.path.lstrip("/") != path:
                    return super().do_GET()
                self.send_response(200)
                self.send_header("Content-Type", "application/octet-stream")
                self.send_header("Connection", "close")
                self.end_headers()
                self.close_connection = True
                chunk = b"\x20" * 65536
                try:
                    for _ in range(size // len(chunk)):
                        self.wfile.write(chunk)
                        flood.sent += len(chunk)
                except OSError:  # the client stopped reading and closed
                    pass

        self.server = http.server.ThreadingHTTPServer(
            ("127.0.0.1", 0), functools.partial(Handler, directory=str(directory))
        )
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}"
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.server.shutdown()
        self.server.server_close()
