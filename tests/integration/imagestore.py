"""An image's blobs and manifests as a registry holds them: two layers (a
shared base, an arch-specific top) for amd64 and arm64 under one tag, an
OCI index over both, and ``serve``: a registry serving it on 127.0.0.1
(tests/integration/conftest.py's platform_registry); test_registry_credentials.py
serves it its own way."""

from __future__ import annotations

import gzip
import hashlib
import http.server
import io
import json
import tarfile
import threading

DOCKER_V2 = "application/vnd.docker.distribution.manifest.v2+json"
OCI_INDEX = "application/vnd.oci.image.index.v1+json"


def digest(data: bytes) -> str:
    return "sha256:" + hashlib.sha256(data).hexdigest()


def layer(name: str) -> tuple[bytes, str]:
    """(gzipped blob, diff id) of a layer holding one file."""
    plain = io.BytesIO()
    with tarfile.open(fileobj=plain, mode="w") as tar:
        info = tarfile.TarInfo(name)
        info.size = len(name)
        tar.addfile(info, io.BytesIO(name.encode()))
    return gzip.compress(plain.getvalue(), mtime=0), digest(plain.getvalue())


class Store:
    """An image of two layers (a shared base, an arch-specific top) for amd64
    and arm64 under one tag."""

    def __init__(self, arches=("amd64", "arm64")):
        self.blobs, self.manifests = {}, {}
        base, base_id = layer("base")
        self.blobs[digest(base)] = base
        entries = []
        self.ids = {}
        for arch in arches:
            top, top_id = layer(f"bin-{arch}")
            self.blobs[digest(top)] = top
            config = json.dumps(
                {"architecture": arch, "os": "linux", "rootfs": {"type": "layers", "diff_ids": [base_id, top_id]}}
            ).encode()
            self.blobs[digest(config)] = config
            self.ids[arch] = digest(config)
            self.diff_ids = {arch: [base_id, top_id], **getattr(self, "diff_ids", {})}
            manifest = json.dumps(
                {
                    "schemaVersion": 2,
                    "mediaType": DOCKER_V2,
                    "config": {"mediaType": "x", "digest": digest(config), "size": len(config)},
                    "layers": [{"mediaType": "y", "digest": digest(b), "size": len(b)} for b in (base, top)],
                }
            ).encode()
            self.manifests[digest(manifest)] = (DOCKER_V2, manifest)
            self.manifests[f"1.0-{arch}"] = (DOCKER_V2, manifest)
            entries.append(
                {
                    "mediaType": DOCKER_V2,
                    "digest": digest(manifest),
                    "size": len(manifest),
                    "platform": {"os": "linux", "architecture": arch},
                }
            )
        self.manifests["1.0"] = (
            OCI_INDEX,
            json.dumps({"schemaVersion": 2, "mediaType": OCI_INDEX, "manifests": entries}).encode(),
        )
        self.top = {
            arch: len(self.blobs[json.loads(self.manifests[f"1.0-{arch}"][1])["layers"][1]["digest"]])
            for arch in arches
        }


def serve():
    """A registry on 127.0.0.1 serving a Store's image until closed: yields (address, store, blobs fetched)."""
    store = Store()
    fetched = []

    class Handler(http.server.BaseHTTPRequestHandler):
        def log_message(self, *args):
            pass

        def do_GET(self):
            # The image under a two-part name and a one-part one (no library/: this is not Docker Hub).
            prefix = next((p for p in ("/v2/ros/payload/", "/v2/payload/") if self.path.startswith(p)), "")
            _, _, repo_rest = self.path.partition(prefix) if prefix else ("", "", "")
            kind, _, ref = repo_rest.partition("/")
            if kind == "manifests" and ref in store.manifests:
                media_type, body = store.manifests[ref]
            elif kind == "blobs" and ref in store.blobs:
                media_type, body = "application/octet-stream", store.blobs[ref]
                fetched.append(ref)
            else:
                self.send_response(404)
                self.end_headers()
                return
            self.send_response(200)
            self.send_header("Content-Type", media_type)
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

    server = http.server.HTTPServer(("127.0.0.1", 0), Handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    yield f"127.0.0.1:{server.server_address[1]}", store, fetched
    server.shutdown()
