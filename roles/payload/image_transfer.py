"""An image sent over SSH into the robot's `docker load`: payload_delivery
push, for robots with no route to the registry.

The image comes from the operator machine's Docker engine (Docker SDK for
Python) over the existing SSH connection, straight into `docker load` on
the command's stdin (no file on the robot: nothing at a path another user
could plant or swap), only when the robot does not have
that exact image (same image id).  Only the layers the robot lacks are sent:
the `docker save` archive is rewritten without the layer files whose chain
(this layer and all below it) the robot already has.  `docker load` looks a
layer up by chain id before it reads the file, so it never opens the ones
left out (checked with Docker 26: 2.1 MB -> 20 KB for a new tag of the same
layers).  Each push is logged on the robot in <payload_dir>/push.log with the
bytes sent.

The robot's own platform: the local engine's image is sent when it is built
for the robot's architecture (from the host snapshot).  Otherwise (a
multi-platform image: a Docker engine with the classic store holds one
variant a tag, the operator's own) the robot's variant is read from the
image's registry (roles/payload/registry.py): the index's entry for its
platform, its config, and only the layer blobs the robot lacks, sent as a
`docker load` archive (the blobs stay gzipped: `docker load` inflates them).
An image with no variant for the robot is refused with one line before
anything is sent.
"""

from __future__ import annotations

import io
import json
import os
import shlex
import tarfile
import tempfile

from pyinfra import host
from pyinfra.api import FunctionCommand, StringCommand

from robotfleet.host import operations
from robotfleet.host.stream import FileStdin
from roles.payload.payloadctl import imageref, platforms

LAYERS_PROBE = "docker image ls -q --no-trunc | sort -u | xargs -r docker image inspect -f '{{json .RootFS.Layers}}'"


def parse_layer_sets(probe_output: str) -> list[list[str]]:
    sets = []
    for line in probe_output.splitlines():
        try:
            layers = json.loads(line)
        except ValueError:
            continue
        if isinstance(layers, list):
            sets.append(layers)
    return sets


def layers_present(diff_ids: list[str], have: list[list[str]]) -> int:
    """How many of the image's bottom layers the robot already has (the
    longest prefix shared with an image on the robot)."""
    best = 0
    for layers in have:
        shared = 0
        for mine, theirs in zip(diff_ids, layers):
            if mine != theirs:
                break
            shared += 1
        best = max(best, shared)
    return best


def local_image(image: str) -> dict | None:
    """{"id", "platform"} of ``image`` in the local Docker engine, or None."""
    import docker

    try:
        attrs = docker.from_env().images.get(image).attrs
    except docker.errors.ImageNotFound:
        return None
    platform = {"os": attrs.get("Os") or "linux", "architecture": attrs.get("Architecture") or ""}
    if attrs.get("Variant"):
        platform["variant"] = attrs["Variant"]
    return {"id": attrs["Id"], "platform": platform}


def registry_variant(image: str, arch: str, insecure: list[str], credentials) -> dict:
    """The robot's variant of ``image`` in its registry: {"id" (the config
    digest: the image id `docker load` gives), "config" (bytes), "layers"
    ([(digest, size)]), "diff_ids", "platform"}; or {"refused": [the
    platforms the registry has]}.  RegistryError when it cannot be read."""
    from roles.payload.registry import Registry

    ref = imageref.parse(image)
    registry = Registry(ref.registry, insecure, credentials)
    media_type, body, _ = registry.manifest(ref.repository, ref.digest or ref.tag)
    manifest = json.loads(body)
    if media_type in platforms.INDEX_TYPES or "manifests" in manifest:
        entries = platforms.index_entries(manifest)
        chosen = platforms.choose(entries, arch)
        if chosen is None:
            return {"refused": [platforms.text(e["platform"]) for e in entries]}
        _, body, _ = registry.manifest(ref.repository, chosen["digest"])
        manifest = json.loads(body)
    config = io.BytesIO()
    registry.blob(ref.repository, manifest["config"]["digest"], config)
    parsed = json.loads(config.getvalue())
    platform = {"os": parsed.get("os") or "linux", "architecture": parsed.get("architecture") or ""}
    if parsed.get("variant"):
        platform["variant"] = parsed["variant"]
    if not platforms.matches(arch, platform):
        return {"refused": [platforms.text(platform)]}
    return {
        "id": manifest["config"]["digest"],
        "config": config.getvalue(),
        "layers": [(layer["digest"], layer["size"]) for layer in manifest["layers"]],
        "diff_ids": parsed["rootfs"]["diff_ids"],
        "platform": platforms.text(platform),
    }


def write_registry_archive(
    image: str, variant: dict, path: str, have: list[list[str]], report: dict, insecure: list[str], credentials
) -> None:
    """A `docker load` archive of the registry ``variant`` into ``path``,
    holding only the layer blobs whose chain the robot lacks."""
    from roles.payload.registry import Registry

    ref = imageref.parse(image)
    registry = Registry(ref.registry, insecure, credentials)
    skip = layers_present(variant["diff_ids"], have)
    config_name = variant["id"].split(":", 1)[1] + ".json"
    names = [f"{digest.split(':', 1)[1]}/layer.tar.gz" for digest, _ in variant["layers"]]
    with tarfile.open(path, "w") as archive:
        _add(archive, config_name, variant["config"])
        for (digest, size), name in list(zip(variant["layers"], names))[skip:]:
            with tempfile.TemporaryFile() as blob:
                registry.blob(ref.repository, digest, blob)
                blob.seek(0)
                info = tarfile.TarInfo(name)
                info.size = size
                archive.addfile(info, blob)
        _add(
            archive,
            "manifest.json",
            json.dumps([{"Config": config_name, "RepoTags": [image], "Layers": names}]).encode(),
        )
    report.update(
        {
            "full": len(variant["config"]) + sum(size for _, size in variant["layers"]),
            "sent": os.path.getsize(path),
            "layers": len(variant["layers"]),
            "skipped": skip,
            "platform": variant["platform"],
        }
    )


def _add(archive: tarfile.TarFile, name: str, data: bytes) -> None:
    info = tarfile.TarInfo(name)
    info.size = len(data)
    archive.addfile(info, io.BytesIO(data))


def write_archive(image: str, path: str, have: list[list[str]], report: dict) -> None:
    """`docker save` of `image` into `path`, without the layers in `have`."""
    import docker

    with tempfile.NamedTemporaryFile(prefix="robotprov-save-", suffix=".tar") as full:
        for chunk in docker.from_env().images.get(image).save(named=image):
            full.write(chunk)
        full.flush()
        report.update(strip_layers(full.name, path, have))


def strip_layers(saved: str, path: str, have: list[list[str]]) -> dict:
    """Copy the `docker save` archive `saved` to `path` (gzipped), leaving out
    the layer files of the bottom layers `have` already holds; returns the
    figures (``sent``: the gzipped size, before base64)."""
    with tarfile.open(saved) as source:
        manifest = json.load(source.extractfile("manifest.json"))
        config = json.load(source.extractfile(manifest[0]["Config"]))
        skip_count = layers_present(config["rootfs"]["diff_ids"], have)
        skip = set(manifest[0]["Layers"][:skip_count])
        # gzip: `docker save` layers are plain tar and the archive travels as
        # base64 (a third larger); `docker load` reads gzip as it is.
        with tarfile.open(path, "w:gz", compresslevel=1) as archive:
            for member in source.getmembers():
                if member.name not in skip:
                    archive.addfile(member, source.extractfile(member) if member.isfile() else None)
    return {
        "full": os.path.getsize(saved),
        "sent": os.path.getsize(path),
        "layers": len(config["rootfs"]["diff_ids"]),
        "skipped": skip_count,
    }


def load_command(archive: str, log_dir: str, image: str, image_id: str, figures: dict) -> StringCommand:
    """`docker load` reading the archive from stdin; logs the push when it
    worked.  Every value reaches the shell as a variable (data), never as
    code: an image name holding `$(...)` is logged as written."""
    q = shlex.quote
    sent = (
        f"sent {figures.get('sent')} of {figures.get('full')} bytes, "
        f"{figures.get('layers', 0) - figures.get('skipped', 0)} of {figures.get('layers')} layers"
        + (f", {figures['platform']} from the registry" if figures.get("platform") else "")
    )
    return operations.shell(
        f"log_dir={q(log_dir)}; image={q(image)}; image_id={q(image_id)}; sent={q(sent)}\n"
        "base64 -d | docker load -q >/dev/null; rc=$?; "
        '[ $rc -eq 0 ] && mkdir -p "$log_dir" && '
        'printf "%s %s %s %s\\n" "$(date -u +%Y-%m-%dT%H:%M:%SZ)" "$image" "$image_id" "$sent" >> "$log_dir/push.log"; '
        "exit $rc",
        stdin=FileStdin(archive),
    )


def choose_source(
    image: str, remote_id: str, robot: str, arch: str, insecure: list[str], credentials, local: dict | None
) -> tuple:
    """What to send the robot: ("send", writer, its arguments after the
    path, image id), ("noop", why) or ("fail", the line).  The local
    engine's image when it is built for the robot's architecture, else the
    robot's variant from the registry."""
    if local is not None and (not arch or platforms.matches(arch, local["platform"])):
        if remote_id == local["id"]:
            return ("noop", f"{image} is already on the host")
        return ("send", write_archive, (), local["id"])
    from roles.payload.registry import RegistryError

    try:
        variant = registry_variant(image, arch, insecure, credentials)
    except (RegistryError, ValueError, KeyError) as error:
        if local is None:
            return (
                "fail",
                f"payload_delivery push: {image} is neither in the local Docker engine "
                f"nor readable from its registry ({error})",
            )
        where = f"in the local Docker engine; its registry: {error}"
        return ("fail", "payload: " + platforms.refusal(robot, arch, image, [platforms.text(local["platform"])], where))
    if "refused" in variant:
        return ("fail", "payload: " + platforms.refusal(robot, arch, image, variant["refused"], "in its registry"))
    if remote_id == variant["id"]:
        return ("noop", f"{image} ({variant['platform']}) is already on the host")
    return ("send", write_registry_archive, (variant,), variant["id"])


@operations.operation()
def push_image(
    image: str,
    remote_id: str,
    remote_layers: list[list[str]],
    log_dir: str,
    robot: str = "",
    arch: str = "",
    insecure: list[str] = (),
    credentials=None,
):
    try:
        local = local_image(image)
    except Exception as error:  # no engine on the operator machine
        yield operations.fail_command(f"payload_delivery push: cannot reach the local Docker engine: {error}")
        return
    decision = choose_source(image, remote_id, robot, arch, list(insecure), credentials, local)
    if decision[0] == "noop":
        host.noop(decision[1])
        return
    if decision[0] == "fail":
        yield operations.fail_command(decision[1])
        return
    _, writer, extra, image_id = decision
    fd, local_path = tempfile.mkstemp(prefix="robotprov-image-", suffix=".tar")
    os.close(fd)
    report: dict = {}
    try:
        if writer is write_archive:
            yield FunctionCommand(write_archive, (image, local_path, remote_layers, report), {})
        else:
            yield FunctionCommand(
                writer, (image, *extra, local_path, remote_layers, report, list(insecure), credentials), {}
            )
        # pyinfra runs each command before asking for the next: report is filled.
        yield load_command(local_path, log_dir, image, image_id, report)
    finally:
        if os.path.exists(local_path):
            os.unlink(local_path)
