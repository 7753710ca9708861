"""A registry's HTTP API (the OCI distribution spec), read from the
operator's machine: what push delivery needs to send a robot its own
variant of a multi-platform image, which a Docker engine with the classic
image store cannot hold (it keeps one variant a tag).

Plain HTTP only for a registry on this machine (localhost, 127.0.0.0/8,
::1) or one the fleet lists in docker_insecure_registries; HTTPS otherwise.
Anonymous, or with a bearer token (anonymous or from the registry's own
credentials, roles/payload/credentials.py), as Docker does.  The
credentials go to this registry only: to a token realm only over HTTPS on
the registry's own host (or its own plain-HTTP host where the registry is
plain HTTP), or to a realm its entry lists; and no Authorization header
follows a redirect to another host (blobs are often served elsewhere).
"""

from __future__ import annotations

import base64
import hashlib
import ipaddress
import json
import re
import urllib.error
import urllib.parse
import urllib.request

from roles.payload.credentials import DOCKER_HUB as DOCKER_HUB_NAMES
from roles.payload.credentials import Credentials, registry_key
from roles.payload.payloadctl import platforms

ACCEPT = ", ".join(platforms.INDEX_TYPES + platforms.MANIFEST_TYPES)
DOCKER_HUB = ("docker.io", "registry-1.docker.io")
TIMEOUT = 60


class RegistryError(Exception):
    """The registry did not give what was asked; the message is one line."""


def loopback(registry: str) -> bool:
    host = urllib.parse.urlsplit(f"//{registry}").hostname or ""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def base_url(registry: str, insecure: list[str] = ()) -> str:
    if registry in DOCKER_HUB:
        return "https://registry-1.docker.io"
    scheme = "http" if loopback(registry) or registry in insecure else "https"
    return f"{scheme}://{registry}"


def path_of(repository: str) -> str:
    """The repository's path on its registry.  As Docker names them, a
    one-part name is an official image under ``library/`` on Docker Hub
    only ("ros", "docker.io/ros" -> "library/ros"); another registry
    serves it as it is ("registry.lan:5000/payload" -> "payload")."""
    first, _, rest = repository.partition("/")
    if rest and ("." in first or ":" in first or first == "localhost"):
        if first not in DOCKER_HUB_NAMES:
            return rest
        repository = rest
    return repository if "/" in repository else f"library/{repository}"


def challenge(header: str) -> tuple[str, dict]:
    """``Bearer realm="...",service="..."`` -> ("bearer", {realm, service, scope})."""
    scheme, _, rest = header.strip().partition(" ")
    return scheme.lower(), dict(re.findall(r'(\w+)="([^"]*)"', rest))


def endpoint(url: str) -> tuple[str, int | None]:
    """(host, port) of ``url``, the port filled in from its scheme."""
    parts = urllib.parse.urlsplit(url)
    return (parts.hostname or "").lower(), parts.port or {"http": 80, "https": 443}.get(parts.scheme)


class SameHostRedirects(urllib.request.HTTPRedirectHandler):
    """Follow redirects, but send the Authorization header only to the host
    that was asked (a registry's blob store on another host gets none)."""

    def redirect_request(self, req, fp, code, msg, headers, newurl):
        new = super().redirect_request(req, fp, code, msg, headers, newurl)
        if new is not None and endpoint(newurl) != endpoint(req.full_url):
            for name in [h for h in new.headers if h.lower() == "authorization"]:
                del new.headers[name]
        return new


class Registry:
    def __init__(self, registry: str, insecure: list[str] = (), credentials: Credentials | None = None):
        self.name = registry
        self.base = base_url(registry, insecure)
        # A credential is for the registry it was configured for, never another.
        mine = credentials is not None and credentials.registry == registry_key(registry)
        self.credentials = credentials if mine else None
        self.authorization: str | None = None
        handlers = [urllib.request.ProxyHandler({})] if loopback(registry) else []
        self.opener = urllib.request.build_opener(*handlers, SameHostRedirects())

    def _basic(self) -> str | None:
        if not self.credentials:
            return None
        secret = f"{self.credentials.username}:{self.credentials.password}"
        return "Basic " + base64.b64encode(secret.encode()).decode()

    def realm_refusal(self, realm: str) -> str | None:
        """Why this registry's credentials may not go to the token ``realm``, or None."""
        parts = urllib.parse.urlsplit(realm)
        own_host = endpoint(realm) == endpoint(self.base)
        if parts.scheme == "http":
            if own_host and self.base.startswith("http://"):
                return None  # the registry itself is plain HTTP (this machine's, or listed insecure)
            return "plain HTTP"
        if parts.scheme != "https":
            return "not an https URL"
        if own_host:
            return None
        listed = {(u.scheme, u.netloc.lower(), u.path) for u in map(urllib.parse.urlsplit, self.credentials.realms)}
        if (parts.scheme, parts.netloc.lower(), parts.path) in listed:
            return None
        return (
            f"on another host ({parts.netloc}) and not listed in "
            f"payload_registry_auths.{self.credentials.registry}.token_realms"
        )

    def _authorize(self, header: str) -> bool:
        scheme, params = challenge(header)
        if scheme == "basic" and self.credentials:
            self.authorization = self._basic()
            return True
        if scheme != "bearer" or "realm" not in params:
            return False
        why = self.realm_refusal(params["realm"]) if self.credentials else None
        if why:
            raise RegistryError(
                f"{self.name}: its token realm {params['realm']} is {why}; the credentials for "
                f"{self.credentials.registry} are not sent there"
            )
        query = urllib.parse.urlencode({k: v for k, v in params.items() if k in ("service", "scope")})
        request = urllib.request.Request(f"{params['realm']}?{query}")
        if self.credentials:
            request.add_header("Authorization", self._basic())
        try:
            with self.opener.open(request, timeout=TIMEOUT) as answer:
                token = json.load(answer)
        except (OSError, ValueError) as error:
            raise RegistryError(f"{self.name}: no token from {params['realm']}: {error}") from None
        self.authorization = "Bearer " + (token.get("token") or token.get("access_token") or "")
        return True

    def open(self, method: str, path: str, headers: dict | None = None, data=None):
        """The answer to ``method path`` (authorizing on a 401 once)."""
        for attempt in (1, 2):
            request = urllib.request.Request(self.base + path, data=data, method=method, headers=dict(headers or {}))
            if self.authorization:
                request.add_header("Authorization", self.authorization)
            try:
                return self.opener.open(request, timeout=TIMEOUT)
            except urllib.error.HTTPError as error:
                if error.code == 401 and attempt == 1 and self._authorize(error.headers.get("WWW-Authenticate", "")):
                    continue
                said = error.read(300).decode(errors="replace").strip().replace("\n", " ")
                raise RegistryError(f"{self.name}: {method} {path}: HTTP {error.code} {said}") from None
            except OSError as error:
                raise RegistryError(f"{self.name}: {method} {path}: {getattr(error, 'reason', error)}") from None
        raise RegistryError(f"{self.name}: {method} {path}: not authorized")

    def manifest(self, repository: str, reference: str) -> tuple[str, bytes, str]:
        """(media type, the manifest's bytes, its digest) of a tag or digest."""
        with self.open("GET", f"/v2/{path_of(repository)}/manifests/{reference}", {"Accept": ACCEPT}) as answer:
            body = answer.read()
            media_type = answer.headers.get("Content-Type", "").split(";")[0].strip()
        digest = "sha256:" + hashlib.sha256(body).hexdigest()
        if reference.startswith("sha256:") and reference != digest:
            raise RegistryError(f"{self.name}: manifest {reference} has the digest {digest}")
        return media_type or json.loads(body).get("mediaType", ""), body, digest

    def blob(self, repository: str, digest: str, out) -> int:
        """Write blob ``digest`` to the file ``out``, checking its digest; its size."""
        check, size = hashlib.sha256(), 0
        with self.open("GET", f"/v2/{path_of(repository)}/blobs/{digest}") as answer:
            while chunk := answer.read(1 << 20):
                check.update(chunk)
                out.write(chunk)
                size += len(chunk)
        if "sha256:" + check.hexdigest() != digest:
            raise RegistryError(f"{self.name}: blob {digest} arrived with another digest")
        return size

    def json_blob(self, repository: str, digest: str) -> dict:
        import io

        buffer = io.BytesIO()
        self.blob(repository, digest, buffer)
        return json.loads(buffer.getvalue())
