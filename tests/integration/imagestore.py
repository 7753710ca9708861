"""An image's blobs and manifests as a registry holds them: two layers (a
shared base, an arch-specific top) for amd64 and arm64 under one tag, an
OCI index over both.  The small registries of test_push_platforms.py and
test_registry_credentials.py serve it."""

from __future__ import annotations

import gzip
import hashlib
import io
import json
import tarfile

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
