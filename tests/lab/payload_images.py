"""The lab's test payload image `ros/payload`: static busybox on scratch.

Tags:
    1.0, 1.1      healthy heartbeat loops that differ only in their version
    1.2-broken    keeps logging but never heartbeats, so its health check fails

In the lab registry every tag is a multi-platform image (an OCI index of
amd64 and arm64; tests/lab/payload_platforms.py), with single-platform
1.0-amd64, 1.0-arm64 and the unrunnable 1.3-exec-format beside them.  The
local engine holds the amd64 images.

`ros/driver` (1.0, 1.1) is the same loop without a HEALTHCHECK (the
Dockerfile's `driver` target), for payloads of several services.

The build context is tests/lab/payload_image/ plus a generated rootfs/ holding
Debian's static busybox (busybox-static, fetched with apt-get download) and one
symlink per applet. No base image from any hub is involved.

CLI: python3 -m tests.lab.payload_images [REGISTRY]
"""

from __future__ import annotations

import hashlib
import json
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import docker

from .engine import get_or_none

REPO_ROOT = Path(__file__).resolve().parents[2]
CONTEXT_DIR = Path(__file__).resolve().parent / "payload_image"
CACHE_DIR = REPO_ROOT / ".lab" / "cache" / "payload-image"
REPOSITORY = "ros/payload"
CONTENT_LABEL = "org.robot-lab.payload.content"

# tag -> build args
TAGS: dict[str, dict[str, str]] = {
    "1.0": {"PAYLOAD_VERSION": "1.0"},
    "1.1": {"PAYLOAD_VERSION": "1.1"},
    "1.2-broken": {"PAYLOAD_VERSION": "1.2-broken", "PAYLOAD_BROKEN": "1"},
}


DRIVER_REPOSITORY = "ros/driver"
DRIVER_TAGS: dict[str, dict[str, str]] = {
    "1.0": {"PAYLOAD_VERSION": "driver-1.0"},
    "1.1": {"PAYLOAD_VERSION": "driver-1.1"},
}
# repository -> (Dockerfile target, tags)
REPOSITORIES = {REPOSITORY: ("payload", TAGS), DRIVER_REPOSITORY: ("driver", DRIVER_TAGS)}


class PayloadImageError(RuntimeError):
    pass


def _log(msg: str) -> None:
    print(f"[payload] {msg}", flush=True)


def static_busybox(cache_dir: Path = CACHE_DIR) -> Path:
    """Path to a cached static busybox binary, fetched from Debian on first use."""
    binary = cache_dir / "busybox"
    if binary.exists():
        return binary
    cache_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        proc = subprocess.run(
            ["apt-get", "-q", "-o", "APT::Sandbox::User=root", "download", "busybox-static"],
            cwd=tmp,
            capture_output=True,
            text=True,
        )
        debs = list(Path(tmp).glob("busybox-static_*.deb"))
        if proc.returncode != 0 or not debs:
            raise PayloadImageError(
                "apt-get download busybox-static failed (run apt-get update?): "
                + (proc.stderr.strip().splitlines() or ["no output"])[-1]
            )
        subprocess.run(["dpkg-deb", "-x", str(debs[0]), f"{tmp}/x"], check=True)
        shutil.copy2(f"{tmp}/x/bin/busybox", binary.with_suffix(".part"))
    binary.with_suffix(".part").rename(binary)
    return binary


def trixie_busyboxes(cache_dir: Path = CACHE_DIR) -> dict[str, Path]:
    """Debian 13's static busybox for amd64 and arm64, one version: the
    arm64 one for the arm64 images, the amd64 one to list the applets
    (running it here needs no emulation)."""
    from .mirror import TrixieApt

    found = {arch: cache_dir / "trixie" / f"busybox-{arch}" for arch in ("amd64", "arm64")}
    if all(path.exists() for path in found.values()):
        return found
    (cache_dir / "trixie").mkdir(parents=True, exist_ok=True)
    source = None
    for arch, path in found.items():
        apt = TrixieApt((cache_dir / "trixie" / f"apt-{arch}").resolve(), arch)
        apt.apt_get("update")
        version = apt.show(["busybox-static"])["busybox-static"]["Version"]
        # A binNMU (+bN) is a rebuild of the same source: the same applets.
        if source not in (None, re.sub(r"\+b\d+$", "", version)):
            raise PayloadImageError(f"Debian trixie's busybox-static is {source} for amd64 but {version} for {arch}")
        source = re.sub(r"\+b\d+$", "", version)
        with tempfile.TemporaryDirectory(dir=cache_dir) as tmp:
            apt.apt_get("download", f"busybox-static={version}", cwd=Path(tmp))
            deb = next(Path(tmp).glob("busybox-static_*.deb"))
            subprocess.run(["dpkg-deb", "-x", str(deb), f"{tmp}/x"], check=True)
            binary = next(p for p in (Path(tmp, "x/usr/bin/busybox"), Path(tmp, "x/bin/busybox")) if p.exists())
            shutil.copy2(binary, path.with_suffix(".part"))
        path.with_suffix(".part").rename(path)
    return found


def applets(busybox: Path) -> list[str]:
    out = subprocess.run([str(busybox), "--list"], capture_output=True, text=True, check=True)
    return sorted(a for a in out.stdout.split() if a != "busybox")


def assemble_context(busybox: Path, dest: Path, applet_names: list[str] | None = None) -> None:
    """Committed context files + rootfs/{bin/busybox, bin/<applet> -> busybox, tmp}."""
    shutil.copytree(CONTEXT_DIR, dest, dirs_exist_ok=True)
    bin_dir = dest / "rootfs" / "bin"
    bin_dir.mkdir(parents=True)
    shutil.copy2(busybox, bin_dir / "busybox")
    (bin_dir / "busybox").chmod(0o755)
    for name in applets(busybox) if applet_names is None else applet_names:
        (bin_dir / name).symlink_to("busybox")
    tmp = dest / "rootfs" / "tmp"
    tmp.mkdir()
    tmp.chmod(0o1777)


def content_hash(busybox: Path, build_args: dict[str, str]) -> str:
    """Identifies what a tag is built from: context files, busybox, build args."""
    h = hashlib.sha256()
    for f in sorted(p for p in CONTEXT_DIR.rglob("*") if p.is_file()):
        h.update(f"{f.relative_to(CONTEXT_DIR)}\0{f.stat().st_mode & 0o777:o}\0".encode())
        h.update(f.read_bytes())
    h.update(hashlib.sha256(busybox.read_bytes()).digest())
    h.update(json.dumps(build_args, sort_keys=True).encode())
    return h.hexdigest()


def _build(
    client: docker.DockerClient,
    context: Path,
    ref: str,
    build_args: dict[str, str],
    content: str,
    target: str = "payload",
):
    try:
        image, _ = client.images.build(
            path=str(context),
            tag=ref,
            buildargs=build_args,
            target=target,
            labels={CONTENT_LABEL: content},
            rm=True,
            forcerm=True,
        )
    except docker.errors.BuildError as e:
        tail = [entry.get("stream", "").strip() for entry in e.build_log][-3:]
        raise PayloadImageError(f"building {ref} failed: {e.msg} {' | '.join(tail)}") from None
    return image


def _push(client: docker.DockerClient, repository: str, tag: str) -> str | None:
    digest = None
    for line in client.images.push(repository, tag=tag, stream=True, decode=True):
        if "error" in line:
            raise PayloadImageError(f"pushing {repository}:{tag} failed: {line['error']}")
        digest = line.get("aux", {}).get("Digest", digest)
    return digest


def build_payload_images(client: docker.DockerClient, registry: str | None = None) -> dict:
    """Build ros/payload:{1.0,1.1,1.2-broken} and ros/driver:{1.0,1.1}; with
    `registry` ("127.0.0.1:5123") also tag and push <registry>/<repository>:<tag>.

    Returns {"repository:tag": {"id": image id, "ref": full ref, "digest": repo digest or None}}.
    """
    start = time.monotonic()
    busybox = static_busybox()
    result = {}
    with tempfile.TemporaryDirectory(prefix="payload-ctx-") as tmp:
        context = Path(tmp) / "ctx"
        assembled = False
        for repository, tag, target, build_args in (
            (repo, tag, target, args) for repo, (target, tags) in REPOSITORIES.items() for tag, args in tags.items()
        ):
            ref = f"{repository}:{tag}"
            content = content_hash(busybox, {**build_args, "target": target})
            image = get_or_none(client.images, ref)
            if image is not None and image.labels.get(CONTENT_LABEL) == content:
                _log(f"{ref} up to date ({image.short_id})")
            else:
                if not assembled:
                    assemble_context(busybox, context)
                    assembled = True
                t = time.monotonic()
                image = _build(client, context, ref, build_args, content, target)
                _log(f"{ref} built in {time.monotonic() - t:.1f}s ({image.short_id})")
            result[ref] = {"id": image.id, "ref": ref, "digest": None}

    if registry:
        t = time.monotonic()
        for local, info in result.items():
            repository, tag = local.rsplit(":", 1)
            remote = f"{registry}/{repository}"
            client.images.get(info["id"]).tag(remote, tag=tag)
            info["ref"] = f"{remote}:{tag}"
            info["digest"] = _push(client, remote, tag)
        _log(f"pushed {len(result)} tags to {registry} in {time.monotonic() - t:.1f}s")
        t = time.monotonic()
        publish_platforms(registry, result)
        _log(f"made {len(result)} tags multi-platform (amd64, arm64) in {time.monotonic() - t:.1f}s")
    _log(f"done in {time.monotonic() - start:.1f}s")
    return result


def publish_platforms(registry: str, result: dict) -> None:
    """Each pushed tag becomes an index of amd64 and arm64 (its ``digest``
    the index's; ``platforms``: each variant's manifest digest)."""
    from roles.payload.registry import RegistryError

    from . import payload_platforms
    from .mirror import MirrorError

    try:
        busyboxes = trixie_busyboxes()
        with tempfile.TemporaryDirectory(prefix="payload-platforms-") as tmp:
            layers = payload_platforms.rootfs_layers(
                assemble_context, busyboxes, applets(busyboxes["amd64"]), Path(tmp)
            )
        for local, info in result.items():
            repository, tag = local.rsplit(":", 1)
            exec_format = layers["exec-format"] if repository == REPOSITORY else None
            # The broken tag keeps the Dockerfile's 2 s probe: judged unhealthy ~8 s after its start.
            broken = REPOSITORIES[repository][1][tag].get("PAYLOAD_BROKEN")
            cadence = None if broken else payload_platforms.HEALTH_CADENCE
            published = payload_platforms.publish(registry, repository, tag, layers["arm64"], exec_format, cadence)
            info["platforms"] = published
            info["digest"] = published["index"]
    except (RegistryError, MirrorError, RuntimeError, ValueError) as error:
        raise PayloadImageError(f"making the payload images multi-platform failed: {error}") from None


def main(argv: list[str]) -> int:
    try:
        result = build_payload_images(docker.from_env(), argv[0] if argv else None)
    except (PayloadImageError, OSError, docker.errors.DockerException) as e:
        print(f"[payload] error: {e}", file=sys.stderr)
        return 1
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
