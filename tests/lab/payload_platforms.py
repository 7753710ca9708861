"""The lab payload as multi-platform images: one tag, an OCI index of an
amd64 and an arm64 image, written to the lab registry through its HTTP API
(Docker 20.10 here has no buildx and its classic builder makes images of its
own architecture only).

The amd64 image is the one `docker build` made and `docker push` sent.  Its
arm64 sibling is the same image with the first layer (the rootfs: busybox and
its applet links) made here from Debian's arm64 busybox-static, and a config
that says linux/arm64/v8: a COPY-only image needs no emulation to build.

Beside the indexes, for the platform tests:
    <tag>-amd64, <tag>-arm64   one platform each (how some vendors ship)
    1.3-exec-format            amd64 by its config, but its busybox is an ELF
                               for no machine this kernel runs (e_machine 0):
                               what a payload built for another architecture
                               looks like to a robot's kernel (ENOEXEC)

A healthy tag's registry copy also gets a health check cadence Docker 20.10's
builder cannot write (`--start-interval`, Docker 25+; the robots run 26):
probed every second until healthy, then every 30 s.  The Dockerfile's 2 s
probe, a `docker exec` each, cost every robot running the payload about 4%
of a core, which the test command's labs paid on their shared two cores; a
payload is still judged healthy within a second of its start.
"""

from __future__ import annotations

import gzip
import hashlib
import io
import json
import os
import tarfile
from pathlib import Path

from roles.payload.registry import Registry, RegistryError, path_of

OCI_INDEX = "application/vnd.oci.image.index.v1+json"
PLATFORMS = {
    "amd64": {"os": "linux", "architecture": "amd64"},
    "arm64": {"os": "linux", "architecture": "arm64", "variant": "v8"},
}
SINGLE_PLATFORM_TAGS = ("1.0",)
EXEC_FORMAT_TAG = ("1.0", "1.3-exec-format")
VERSION_LABEL = "org.opencontainers.image.version"


def digest_of(data: bytes) -> str:
    return "sha256:" + hashlib.sha256(data).hexdigest()


def layer_tar(rootfs: Path) -> bytes:
    """The rootfs as an image layer: the same bytes for the same files
    (sorted, owned by root, time 0)."""
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w", format=tarfile.PAX_FORMAT) as tar:
        for path in sorted(rootfs.rglob("*")):
            info = tar.gettarinfo(str(path), arcname=str(path.relative_to(rootfs)))
            info.uid = info.gid = 0
            info.uname = info.gname = ""
            info.mtime = 0
            if info.isfile():
                with open(path, "rb") as f:
                    tar.addfile(info, f)
            else:
                tar.addfile(info)
    return buffer.getvalue()


def without_machine(elf: bytes) -> bytes:
    """An ELF program whose e_machine (bytes 18-19) names no machine."""
    if elf[:4] != b"\x7fELF":
        raise ValueError("not an ELF program")
    return elf[:18] + b"\x00\x00" + elf[20:]


def variant_config(config: dict, diff_id: str, platform: dict, version: str | None = None) -> dict:
    """``config`` with another first layer and platform (and version label)."""
    changed = json.loads(json.dumps(config))
    changed.pop("variant", None)
    changed.update({"architecture": platform["architecture"], "os": platform["os"]})
    if platform.get("variant"):
        changed["variant"] = platform["variant"]
    changed["rootfs"]["diff_ids"][0] = diff_id
    if version:
        for key in ("config", "container_config"):
            if isinstance(changed.get(key), dict) and isinstance(changed[key].get("Labels"), dict):
                changed[key]["Labels"][VERSION_LABEL] = version
    return changed


SECOND = 1_000_000_000  # the image config's durations are nanoseconds
HEALTH_CADENCE = {"StartInterval": SECOND, "StartPeriod": 30 * SECOND, "Interval": 30 * SECOND}


def with_health_cadence(config: dict, cadence: dict) -> dict:
    """``config`` with its HEALTHCHECK's timings replaced by ``cadence``
    (what the check runs and its retries kept); unchanged without one."""
    changed = json.loads(json.dumps(config))
    health = (changed.get("config") or {}).get("Healthcheck")
    if health:
        health.update(cadence)
    return changed


def index_document(entries: list[tuple[str, bytes, str, dict]]) -> bytes:
    """An OCI index of (media type, manifest, digest, platform) entries."""
    return json.dumps(
        {
            "schemaVersion": 2,
            "mediaType": OCI_INDEX,
            "manifests": [
                {"mediaType": media_type, "digest": digest, "size": len(body), "platform": platform}
                for media_type, body, digest, platform in entries
            ],
        },
        indent=2,
    ).encode()


class Writer(Registry):
    """The lab registry, written to (blobs, manifests)."""

    def has_blob(self, repository: str, digest: str) -> bool:
        try:
            with self.open("HEAD", f"/v2/{path_of(repository)}/blobs/{digest}"):
                return True
        except RegistryError:
            return False

    def put_blob(self, repository: str, data: bytes) -> str:
        digest = digest_of(data)
        if self.has_blob(repository, digest):
            return digest
        with self.open("POST", f"/v2/{path_of(repository)}/blobs/uploads/", data=b"") as answer:
            location = answer.headers["Location"]
        if location.startswith("http"):
            location = "/" + location.split("/", 3)[3]
        joiner = "&" if "?" in location else "?"
        with self.open("PUT", f"{location}{joiner}digest={digest}", {"Content-Type": "application/octet-stream"}, data):
            pass
        return digest

    def put_manifest(self, repository: str, reference: str, media_type: str, body: bytes) -> str:
        with self.open("PUT", f"/v2/{path_of(repository)}/manifests/{reference}", {"Content-Type": media_type}, body):
            pass
        return digest_of(body)


def publish(
    registry: str,
    repository: str,
    tag: str,
    arm64_rootfs: bytes,
    exec_format_rootfs: bytes | None,
    health_cadence: dict | None = None,
) -> dict:
    """Make ``repository:tag`` (pushed by Docker, amd64) an index of amd64
    and arm64, and write the single-platform tags; returns the digests.
    ``health_cadence``: the HEALTHCHECK timings every variant gets."""
    writer = Writer(registry)
    media_type, amd64_body, amd64_digest = writer.manifest(repository, tag)
    if media_type == OCI_INDEX:
        raise RuntimeError(f"{repository}:{tag} is already an index: push the amd64 image first")
    amd64 = json.loads(amd64_body)
    config = writer.json_blob(repository, amd64["config"]["digest"])
    if len(config["rootfs"]["diff_ids"]) != 2:
        raise RuntimeError(f"{repository}:{tag}: expected the rootfs layer and the scripts layer")
    if health_cadence and (config.get("config") or {}).get("Healthcheck"):
        config = with_health_cadence(config, health_cadence)
        new_config = json.dumps(config, sort_keys=True).encode()
        writer.put_blob(repository, new_config)
        amd64["config"].update(digest=digest_of(new_config), size=len(new_config))
        amd64_body = json.dumps(amd64, indent=3).encode()
        amd64_digest = writer.put_manifest(repository, digest_of(amd64_body), media_type, amd64_body)

    def variant(rootfs: bytes, platform: dict, version: str | None = None) -> tuple[bytes, str]:
        blob = gzip.compress(rootfs, mtime=0)
        writer.put_blob(repository, blob)
        new_config = json.dumps(variant_config(config, digest_of(rootfs), platform, version), sort_keys=True).encode()
        writer.put_blob(repository, new_config)
        manifest = json.loads(amd64_body)
        manifest["config"].update(digest=digest_of(new_config), size=len(new_config))
        manifest["layers"][0].update(digest=digest_of(blob), size=len(blob))
        body = json.dumps(manifest, indent=3).encode()
        return body, writer.put_manifest(repository, digest_of(body), media_type, body)

    arm64_body, arm64_digest = variant(arm64_rootfs, PLATFORMS["arm64"])
    published = {"amd64": amd64_digest, "arm64": arm64_digest}
    if tag in SINGLE_PLATFORM_TAGS:
        writer.put_manifest(repository, f"{tag}-amd64", media_type, amd64_body)
        writer.put_manifest(repository, f"{tag}-arm64", media_type, arm64_body)
    if exec_format_rootfs is not None and tag == EXEC_FORMAT_TAG[0]:
        body, digest = variant(exec_format_rootfs, PLATFORMS["amd64"], EXEC_FORMAT_TAG[1])
        writer.put_manifest(repository, EXEC_FORMAT_TAG[1], media_type, body)
        published["exec-format"] = digest
    index = index_document(
        [
            (media_type, amd64_body, amd64_digest, PLATFORMS["amd64"]),
            (media_type, arm64_body, arm64_digest, PLATFORMS["arm64"]),
        ]
    )
    published["index"] = writer.put_manifest(repository, tag, OCI_INDEX, index)
    return published


def rootfs_layers(assemble, busyboxes: dict[str, Path], applet_names: list[str], work: Path) -> dict[str, bytes]:
    """The arm64 rootfs layer and the exec-format one, from ``assemble``
    (payload_images.assemble_context) with each busybox."""
    layers = {}
    exec_format = work / "busybox-exec-format"
    exec_format.write_bytes(without_machine(busyboxes["amd64"].read_bytes()))
    os.chmod(exec_format, 0o755)
    for name, busybox in (("arm64", busyboxes["arm64"]), ("exec-format", exec_format)):
        context = work / f"ctx-{name}"
        assemble(busybox, context, applet_names)
        layers[name] = layer_tar(context / "rootfs")
    return layers
