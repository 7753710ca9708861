"""The registry client push delivery reads multi-platform images with
(roles/payload/registry.py) talking to a registry: the token handshake
registries such as Docker Hub ask for (no registry with token auth runs in
the lab: a small server here plays it), and a registry that is not there.
Its pure rules are in tests/unit/test_registry_rules.py."""

import hashlib
import http.server
import importlib
import json
import threading

import pytest


@pytest.fixture(autouse=True)
def _registry():
    # Imported when a test runs: urllib imports ssl, which pyinfra's gevent
    # must patch first where both share a process (tests/conftest.py).
    global registry
    registry = importlib.import_module("roles.payload.registry")


MANIFEST = json.dumps(
    {"schemaVersion": 2, "mediaType": "application/vnd.oci.image.index.v1+json", "manifests": []}
).encode()


@pytest.fixture
def token_registry():
    """A registry that answers only with a bearer token from its own realm."""
    seen = []

    class Handler(http.server.BaseHTTPRequestHandler):
        def log_message(self, *args):
            pass

        def do_GET(self):
            seen.append((self.path, self.headers.get("Authorization"), self.headers.get("Accept")))
            port = self.server.server_address[1]
            if self.path.startswith("/token"):
                body = json.dumps({"token": "t0k"}).encode()
                self.send_response(200)
            elif self.headers.get("Authorization") != "Bearer t0k":
                body = b'{"errors": [{"code": "UNAUTHORIZED"}]}'
                self.send_response(401)
                self.send_header(
                    "WWW-Authenticate",
                    f'Bearer realm="http://127.0.0.1:{port}/token",service="lab",scope="repository:ros/payload:pull"',
                )
            else:
                body = MANIFEST
                self.send_response(200)
                self.send_header("Content-Type", "application/vnd.oci.image.index.v1+json")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

    server = http.server.HTTPServer(("127.0.0.1", 0), Handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield f"127.0.0.1:{server.server_address[1]}", seen
    server.shutdown()


def test_a_token_is_fetched_once_and_sent(token_registry):
    address, seen = token_registry
    from roles.payload.credentials import Credentials

    client = registry.Registry(address, credentials=Credentials(address, "robot", "secret"))
    media_type, body, digest = client.manifest(f"{address}/ros/payload", "1.0")
    assert media_type == "application/vnd.oci.image.index.v1+json" and body == MANIFEST
    assert digest == "sha256:" + hashlib.sha256(MANIFEST).hexdigest()
    paths = [path for path, _, _ in seen]
    assert paths == [
        "/v2/ros/payload/manifests/1.0",
        "/token?service=lab&scope=repository%3Aros%2Fpayload%3Apull",
        "/v2/ros/payload/manifests/1.0",
    ]
    assert seen[1][1].startswith("Basic ")  # the credentials go to the token realm only (the registry's own host)
    assert seen[2][1] == "Bearer t0k" and "application/vnd.oci.image.index.v1+json" in seen[2][2]


def test_a_registry_that_is_not_there_is_one_line():
    with pytest.raises(registry.RegistryError) as refused:
        registry.Registry("127.0.0.1:1").manifest("127.0.0.1:1/ros/payload", "1.0")
    assert str(refused.value).startswith("127.0.0.1:1: GET /v2/ros/payload/manifests/1.0: ")
    assert "\n" not in str(refused.value)


def test_a_manifest_asked_by_digest_must_have_that_digest(token_registry):
    address, _ = token_registry
    with pytest.raises(registry.RegistryError, match="has the digest"):
        registry.Registry(address).manifest(f"{address}/ros/payload", "sha256:" + "0" * 64)
