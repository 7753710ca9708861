"""The payload's part in a release on removable media (``robotfleet
export``): each pinned image as a ``docker load`` archive, read from its
registry with the registry client push delivery uses (its own credentials
only, the fleet's insecure registries), so the operator's machine needs no
Docker engine.

One archive loads on both of Docker's image stores: it is an OCI image
layout (``oci-layout``, ``index.json`` naming the exact manifest bytes the
registry gave, so the containerd image store keeps the digest the release
pins) and a ``docker save`` archive (``manifest.json``, which the classic
store reads: it keeps the image id, the config's digest, but no registry
digest).  Both name the same blobs under ``blobs/sha256/``; layers stay as
the registry gave them (gzipped: ``docker load`` inflates them).  Only the
robot's own variant of a multi-platform image is carried.
"""

from __future__ import annotations

import io
import json
import tarfile
import tempfile

from roles.payload.payloadctl import imageref, platforms

OCI_LAYOUT = b'{"imageLayoutVersion": "1.0.0"}'
OCI_INDEX = "application/vnd.oci.image.index.v1+json"


def full_name(ref: imageref.ImageRef) -> str:
    """The name as Docker normalizes it (docker.io/library/ros for ros)."""
    if ref.registry != "docker.io":
        return ref.repository
    path = ref.repository.split("/", 1)[1] if ref.repository.startswith("docker.io/") else ref.repository
    return f"docker.io/{path if '/' in path else 'library/' + path}"


def _add(archive: tarfile.TarFile, name: str, data: bytes) -> None:
    info = tarfile.TarInfo(name)
    info.size = len(data)
    info.mode = 0o644
    archive.addfile(info, io.BytesIO(data))


def _blob_name(digest: str) -> str:
    return f"blobs/sha256/{digest.split(':', 1)[1]}"


def write(text: str, digest: str, machine: str, path, insecure: list[str], own) -> str:
    """Write the archive of image ``text`` at ``digest`` (the release's pin:
    a manifest, or an index whose variant for ``machine`` is carried) into
    ``path``, read with the registry's ``own`` credentials; its image id
    (the config's digest).  ValueError with one line."""
    from roles.payload.registry import Registry, RegistryError

    ref = imageref.parse(text)
    registry = Registry(ref.registry, insecure, own)
    arch = platforms.go_arch(machine)
    try:
        top_type, top, _ = registry.manifest(ref.repository, digest)  # checked against the pin
        manifest = top
        if top_type in platforms.INDEX_TYPES or "manifests" in json.loads(top):
            entries = platforms.index_entries(json.loads(top))
            chosen = platforms.choose(entries, arch)
            if chosen is None:
                raise ValueError(
                    f"image {text}@{digest} has no variant for {machine} (it has: "
                    f"{', '.join(platforms.text(e['platform']) for e in entries) or 'none'})"
                )
            _, manifest, _ = registry.manifest(ref.repository, chosen["digest"])
        parsed = json.loads(manifest)
        config = io.BytesIO()
        registry.blob(ref.repository, parsed["config"]["digest"], config)
        image = json.loads(config.getvalue())
        if not platforms.matches(arch, {"os": image.get("os") or "linux", "architecture": image.get("architecture")}):
            raise ValueError(
                f"image {text}@{digest} is built for {image.get('os')}/{image.get('architecture')}, not {machine}"
            )
        name = full_name(ref)
        tagged = f"{name}:{ref.tag}" if ref.tag else None
        layers = [layer["digest"] for layer in parsed["layers"]]
        with tarfile.open(path, "w") as out:
            _add(out, "oci-layout", OCI_LAYOUT)
            annotations = {"io.containerd.image.name": tagged or f"{name}@{digest}"}
            if ref.tag:
                annotations["org.opencontainers.image.ref.name"] = ref.tag
            _add(
                out,
                "index.json",
                json.dumps(
                    {
                        "schemaVersion": 2,
                        "mediaType": OCI_INDEX,
                        "manifests": [
                            {"mediaType": top_type, "digest": digest, "size": len(top), "annotations": annotations}
                        ],
                    }
                ).encode(),
            )
            _add(out, _blob_name(digest), top)
            if manifest is not top:
                _add(out, _blob_name("sha256:" + _sha256(manifest)), manifest)
            _add(out, _blob_name(parsed["config"]["digest"]), config.getvalue())
            for layer in dict.fromkeys(layers):
                with tempfile.TemporaryFile() as blob:
                    size = registry.blob(ref.repository, layer, blob)
                    blob.seek(0)
                    info = tarfile.TarInfo(_blob_name(layer))
                    info.size, info.mode = size, 0o644
                    out.addfile(info, blob)
            _add(
                out,
                "manifest.json",
                json.dumps(
                    [
                        {
                            "Config": _blob_name(parsed["config"]["digest"]),
                            "RepoTags": [tagged] if tagged else [],
                            "Layers": [_blob_name(layer) for layer in layers],
                        }
                    ]
                ).encode(),
            )
    except RegistryError as error:
        raise ValueError(f"image {text}: {error}") from None
    except (KeyError, TypeError, json.JSONDecodeError) as error:
        raise ValueError(f"image {text}@{digest}: not an image manifest its registry gave ({error})") from None
    return parsed["config"]["digest"]


def _sha256(data: bytes) -> str:
    import hashlib

    return hashlib.sha256(data).hexdigest()
