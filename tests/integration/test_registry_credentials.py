"""Registry credentials stay with their registry (issue 27, item 1).

Real HTTP(S) servers on 127.0.0.1 play the registries: the one the
credentials are for, and a hostile one (another registry of a multi-service
payload, a token realm on another host, a blob store a redirect points at)
that records every connection and header it receives: it must receive no
credential."""

from __future__ import annotations

import base64
import datetime
import http.server
import importlib
import ipaddress
import json
import ssl
import threading

import pyinfra_cli  # noqa: F401  (gevent patches first: these servers then run as greenlets beside pyinfra)
import pytest

from tests.integration.imagestore import Store
from tests.unit.harness import ROBOT, converged, find, plan

USER, PASSWORD = "robot", "s3cret-primary"
BASIC = "Basic " + base64.b64encode(f"{USER}:{PASSWORD}".encode()).decode()


@pytest.fixture(autouse=True)
def _modules():
    # Imported when a test runs: urllib imports ssl, which pyinfra's gevent
    # must patch first where both share a process (tests/unit/conftest.py).
    global registry, credentials
    registry = importlib.import_module("roles.payload.registry")
    credentials = importlib.import_module("roles.payload.credentials")


class Server:
    """A registry (or token service, or blob store) on 127.0.0.1 serving
    ``store`` under any repository, recording each connection and each
    request's (path, Authorization).  ``answer(handler)`` may answer first
    (return True when it did)."""

    def __init__(self, store: Store | None = None, answer=None, tls: ssl.SSLContext | None = None):
        self.store, self.answer, self.connections, self.seen = store or Store(), answer, 0, []
        server = self

        class Handler(http.server.BaseHTTPRequestHandler):
            def log_message(self, *args):
                pass

            def setup(self):
                server.connections += 1
                super().setup()

            def do_GET(self):
                server.seen.append((self.path, self.headers.get("Authorization")))
                if server.answer and server.answer(self):
                    return
                kind, ref = self.path.split("/")[-2:] if self.path.startswith("/v2/") else ("", "")
                found = (
                    server.store.manifests.get(ref)
                    if kind == "manifests"
                    else ("application/octet-stream", server.store.blobs[ref])
                    if ref in server.store.blobs
                    else None
                )
                if found is None:
                    return send(self, 404, b"{}")
                send(self, 200, found[1], {"Content-Type": found[0]})

        self.httpd = http.server.HTTPServer(("127.0.0.1", 0), Handler)
        if tls is not None:
            self.httpd.socket = tls.wrap_socket(self.httpd.socket, server_side=True)
        self.address = f"127.0.0.1:{self.httpd.server_address[1]}"
        threading.Thread(target=self.httpd.serve_forever, daemon=True).start()

    @property
    def authorizations(self) -> list:
        return [auth for _, auth in self.seen]


def send(handler, code: int, body: bytes, headers: dict | None = None) -> bool:
    handler.send_response(code)
    for key, value in (headers or {}).items():
        handler.send_header(key, value)
    handler.send_header("Content-Length", str(len(body)))
    handler.end_headers()
    handler.wfile.write(body)
    return True


def basic_only(handler) -> bool:
    """A registry asking for Basic auth: 401 unless the right credentials come."""
    if handler.headers.get("Authorization") == BASIC:
        return False
    return send(handler, 401, b"{}", {"WWW-Authenticate": 'Basic realm="registry"'})


def bearer_from(realm: str):
    def answer(handler) -> bool:
        if handler.headers.get("Authorization") == "Bearer t0k":
            return False
        return send(handler, 401, b"{}", {"WWW-Authenticate": f'Bearer realm="{realm}",service="reg",scope="x"'})

    return answer


def token_service(handler) -> bool:
    return send(handler, 200, json.dumps({"token": "t0k"}).encode())


@pytest.fixture
def servers():
    started = []

    def start(*args, **kwargs) -> Server:
        started.append(Server(*args, **kwargs))
        return started[-1]

    yield start
    for server in started:
        server.httpd.shutdown()


def own(registry_address: str, *realms: str):
    return credentials.Credentials(registry_address, USER, PASSWORD, realms)


# -- push: each image is read with its own registry's credentials ------------


def test_push_of_a_multi_service_payload_sends_the_primary_password_to_no_other_registry(servers, monkeypatch):
    """The real deploy (the plan harness: the payload role's steps, the
    local Docker engine that lacks these images, the registry client): the
    primary registry gets its credentials, the second registry (hostile, it
    asks for Basic auth to collect them) gets none."""
    primary, hostile = (
        servers(answer=basic_only),
        servers(answer=lambda h: send(h, 401, b"{}", {"WWW-Authenticate": 'Basic realm="give me yours"'})),
    )
    monkeypatch.setenv("PAYLOAD_REGISTRY_USERNAME", USER)
    monkeypatch.setenv("PAYLOAD_REGISTRY_PASSWORD", PASSWORD)
    data = {
        **ROBOT,
        "payload_image": None,
        "udev_sensors": [],
        "payload_delivery": "push",
        "payload_services": {
            "main": {"image": f"{primary.address}/ros/payload:1.0"},
            "tools": {"image": f"{hostile.address}/ros/tools:1.0"},
        },
    }
    result = plan({"r1": ("robots", data, converged("robots", data, "debian-13"))})
    assert BASIC in primary.authorizations  # the primary image was read with its credentials
    assert hostile.seen and set(hostile.authorizations) == {None}
    (refused,) = find(result["r1"], "tools:1.0 is neither in the local Docker engine nor readable")
    assert "HTTP 401" in refused and PASSWORD not in refused


def test_a_pull_release_resolves_each_image_with_its_own_registrys_credentials(servers, monkeypatch):
    """robotfleet publish pins every image's digest (roles/payload/pins.py): the
    primary registry's password goes to the primary registry only."""
    from robotfleet.pull.protocol.robot_data import HostData
    from roles.payload import pins

    primary = servers(answer=basic_only)
    hostile = servers(answer=lambda h: send(h, 401, b"{}", {"WWW-Authenticate": 'Basic realm="give me yours"'}))
    monkeypatch.setenv("PAYLOAD_REGISTRY_USERNAME", USER)
    monkeypatch.setenv("PAYLOAD_REGISTRY_PASSWORD", PASSWORD)
    data = HostData(
        payload_registry_username_env="PAYLOAD_REGISTRY_USERNAME",
        payload_registry_password_env="PAYLOAD_REGISTRY_PASSWORD",
        docker_insecure_registries=[],
        payload_services={
            "main": {"image": f"{primary.address}/ros/payload:1.0"},
            "tools": {"image": f"{hostile.address}/ros/tools:1.0"},
        },
    )
    first = f"{primary.address}/ros/payload:1.0"
    assert pins.resolve(data, [first])[first].startswith("sha256:") and BASIC in primary.authorizations
    with pytest.raises(ValueError, match="HTTP 401"):
        pins.resolve(data, [f"{hostile.address}/ros/tools:1.0"])
    assert hostile.seen and set(hostile.authorizations) == {None}


def test_a_registry_client_drops_credentials_given_for_another_registry(servers):
    hostile = servers(answer=basic_only)
    client = registry.Registry(hostile.address, credentials=own("reg.example.com"))
    with pytest.raises(registry.RegistryError, match="HTTP 401"):
        client.manifest(f"{hostile.address}/ros/payload", "1.0")
    assert set(hostile.authorizations) == {None}


# -- token realms -------------------------------------------------------------


def test_no_credentials_to_a_plain_http_token_realm_on_another_host(servers):
    realm = servers(answer=token_service)
    primary = servers(answer=bearer_from(f"http://{realm.address}/token"))
    with pytest.raises(registry.RegistryError) as refused:
        registry.Registry(primary.address, credentials=own(primary.address)).manifest(
            f"{primary.address}/ros/payload", "1.0"
        )
    assert str(refused.value) == (
        f"{primary.address}: its token realm http://{realm.address}/token is plain HTTP; "
        f"the credentials for {primary.address} are not sent there"
    )
    assert realm.connections == 0


def test_the_same_plain_http_host_as_a_plain_http_registry_may_be_its_realm(servers):
    primary = servers()
    primary.answer = lambda h: (
        token_service(h) if h.path.startswith("/token") else bearer_from(f"http://{primary.address}/token")(h)
    )
    client = registry.Registry(primary.address, credentials=own(primary.address))
    assert client.manifest(f"{primary.address}/ros/payload", "1.0")[0] == "application/vnd.oci.image.index.v1+json"
    assert (next(a for p, a in primary.seen if p.startswith("/token")), primary.authorizations[-1]) == (
        BASIC,
        "Bearer t0k",
    )


@pytest.fixture(scope="module")
def tls(tmp_path_factory):
    """A CA this test trusts (SSL_CERT_FILE) and a server context for 127.0.0.1 signed by it."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    base = tmp_path_factory.mktemp("tls")
    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "127.0.0.1")])
    now = datetime.datetime.now(datetime.timezone.utc)
    cert = (
        x509.CertificateBuilder()
        .subject_name(name)
        .issuer_name(name)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(hours=1))
        .add_extension(x509.SubjectAlternativeName([x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]), False)
        .add_extension(x509.BasicConstraints(ca=True, path_length=None), True)
        .sign(key, hashes.SHA256())
    )
    (base / "cert.pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    (base / "key.pem").write_bytes(
        key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption())
    )
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    context.load_cert_chain(base / "cert.pem", base / "key.pem")
    return context, str(base / "cert.pem")


def test_an_https_realm_on_another_host_gets_them_only_when_listed(servers, tls, monkeypatch):
    context, ca = tls
    monkeypatch.setenv("SSL_CERT_FILE", ca)
    realm = servers(answer=token_service, tls=context)
    primary = servers(answer=bearer_from(f"https://{realm.address}/token"))
    with pytest.raises(registry.RegistryError) as refused:
        registry.Registry(primary.address, credentials=own(primary.address)).manifest(
            f"{primary.address}/ros/payload", "1.0"
        )
    assert str(refused.value) == (
        f"{primary.address}: its token realm https://{realm.address}/token is on another host ({realm.address}) "
        f"and not listed in payload_registry_auths.{primary.address}.token_realms; the credentials for "
        f"{primary.address} are not sent there"
    )
    assert realm.connections == 0
    listed = registry.Registry(primary.address, credentials=own(primary.address, f"https://{realm.address}/token"))
    assert listed.manifest(f"{primary.address}/ros/payload", "1.0")[0] == "application/vnd.oci.image.index.v1+json"
    assert realm.authorizations == [BASIC] and primary.authorizations[-1] == "Bearer t0k"


def test_anonymous_token_requests_go_where_the_registry_says():
    client = registry.Registry("reg.example.com", credentials=None)
    assert client.credentials is None  # nothing to protect: Docker Hub's public images keep working
    hub = registry.Registry("docker.io", credentials=own("docker.io", *credentials.KNOWN_REALMS["docker.io"]))
    assert hub.realm_refusal("https://auth.docker.io/token") is None
    assert hub.realm_refusal("http://auth.docker.io/token") == "plain HTTP"
    tls_registry = registry.Registry("reg.example.com", credentials=own("reg.example.com"))
    assert tls_registry.realm_refusal("https://reg.example.com/token") is None
    assert tls_registry.realm_refusal("https://reg.example.com:443/v2/token") is None
    assert tls_registry.realm_refusal("http://reg.example.com/token") == "plain HTTP"  # the registry is HTTPS


# -- redirects ----------------------------------------------------------------


def test_no_credentials_follow_a_redirect_to_another_host(servers, tmp_path):
    store = Store()
    blob_store = servers(store=store)
    primary = servers(store=store)

    def answer(handler) -> bool:
        if basic_only(handler):
            return True
        if "/blobs/" in handler.path:  # as registries send blobs to their storage
            return send(
                handler, 307, b"", {"Location": f"http://{blob_store.address}/v2/x/blobs/{handler.path.split('/')[-1]}"}
            )
        return False

    primary.answer = answer
    client = registry.Registry(primary.address, credentials=own(primary.address))
    config = next(d for d, b in store.blobs.items() if b.startswith(b"{"))
    assert client.json_blob(f"{primary.address}/ros/payload", config)["os"] == "linux"
    assert blob_store.seen and set(blob_store.authorizations) == {None}
    assert primary.authorizations[-1] == BASIC


def test_a_redirect_on_the_same_host_keeps_them(servers):
    primary = servers()

    def answer(handler) -> bool:
        if basic_only(handler):
            return True
        if handler.path.startswith("/v2/ros/payload/blobs/"):
            return send(handler, 307, b"", {"Location": "/v2/storage/blobs/" + handler.path.split("/")[-1]})
        return False

    primary.answer = answer
    config = next(d for d, b in primary.store.blobs.items() if b.startswith(b"{"))
    registry.Registry(primary.address, credentials=own(primary.address)).json_blob(
        f"{primary.address}/ros/payload", config
    )
    assert primary.seen[-1] == (f"/v2/storage/blobs/{config}", BASIC)


# -- pull: one login per registry, each with its own password ----------------


def test_pull_logs_in_to_each_registry_with_its_own_credentials(monkeypatch, tmp_path):
    password_file = tmp_path / "reg2-password"
    password_file.write_text("s3cret-second\n")
    monkeypatch.setenv("PAYLOAD_REGISTRY_USERNAME", USER)
    monkeypatch.setenv("PAYLOAD_REGISTRY_PASSWORD", PASSWORD)
    monkeypatch.setenv("REG2_USER", "puller2")
    data = {
        **ROBOT,
        "payload_image": None,
        "udev_sensors": [],
        "payload_services": {
            "main": {"image": "reg.example.com/ros/payload:1.0"},
            "tools": {"image": "reg2.example.com:5000/ros/tools:1.0"},
            "db": {"image": "docker.io/library/postgres:16"},
        },
        "payload_registry_auths": {
            "reg2.example.com:5000": {"username_env": "REG2_USER", "password_file": str(password_file)}
        },
    }
    result = plan({"r1": ("robots", data, converged("robots", data, "debian-13"))})
    assert result.failed == set()
    logins = find(result["r1"], "docker login")
    assert len(logins) == 2, logins
    first, second = sorted(logins, key=lambda c: "reg2" in c)
    assert "docker login reg.example.com --username robot --password-stdin" in first
    assert "docker login reg2.example.com:5000 --username puller2 --password-stdin" in second
    assert first.stdin.rstrip("\n").endswith(PASSWORD) and "s3cret-second" not in first.stdin
    assert second.stdin.rstrip("\n").endswith("s3cret-second") and PASSWORD not in second.stdin
    assert not [c for c in result["r1"] if "docker.io" in c and "login" in c]  # no credentials for Docker Hub


def test_a_configured_registry_whose_credentials_are_missing_fails_the_host_in_one_line(monkeypatch):
    monkeypatch.delenv("REG2_PASSWORD", raising=False)
    monkeypatch.setenv("REG2_USER", "puller2")
    data = {
        **ROBOT,
        "payload_registry_auths": {"reg.example.com": {"username_env": "REG2_USER", "password_env": "REG2_PASSWORD"}},
    }
    result = plan({"r1": ("robots", data, converged("robots", data, "debian-13"))})
    assert result.failed == {"r1"}
    (line,) = find(result["r1"], "payload_registry_auths")
    assert "payload: payload_registry_auths.reg.example.com: password_env REG2_PASSWORD is not set" in line


def test_the_registry_passwords_are_the_roles_secrets(monkeypatch, tmp_path):
    password_file = tmp_path / "p"
    password_file.write_text("from-a-file")
    monkeypatch.setenv("PAYLOAD_REGISTRY_USERNAME", USER)
    monkeypatch.setenv("PAYLOAD_REGISTRY_PASSWORD", PASSWORD)
    data = {
        "payload_image": "reg.example.com/p:1",
        "payload_registry_username_env": "PAYLOAD_REGISTRY_USERNAME",
        "payload_registry_password_env": "PAYLOAD_REGISTRY_PASSWORD",
        "payload_registry_auths": {
            "index.docker.io": {"username_env": "PAYLOAD_REGISTRY_USERNAME", "password_file": str(password_file)}
        },
    }
    assert sorted(credentials.secrets(data)) == sorted([PASSWORD, "from-a-file"])
    assert credentials.lookup(data, "registry-1.docker.io").realms == ("https://auth.docker.io/token",)
    assert PASSWORD not in repr(credentials.lookup(data, "reg.example.com"))
