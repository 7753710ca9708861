"""payload_delivery: push — for robots with no route to the registry.

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
"""

from __future__ import annotations

import base64
import json
import os
import shlex
import tarfile
import tempfile

from pyinfra import host
from pyinfra.api import FunctionCommand, StringCommand

from engine.host import operations

LAYERS_PROBE = (
    "docker image ls -q --no-trunc | sort -u | "
    "xargs -r docker image inspect -f '{{json .RootFS.Layers}}'"
)


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


def local_image_id(image: str) -> str | None:
    import docker

    try:
        return docker.from_env().images.get(image).id
    except docker.errors.ImageNotFound:
        return None


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


class ArchiveStdin(list):
    """The archive at ``path`` as base64 lines for a command's stdin, read
    from disk while it is sent, so an image never sits whole in memory.  A
    list because pyinfra's write_stdin iterates lists; read afresh each time
    (pyinfra resends stdin when sudo asks for a password)."""

    CHUNK = 57 * 1024  # a multiple of 57 bytes: whole 76-character base64 lines

    def __init__(self, path: str):
        super().__init__()
        self.path = path

    def __bool__(self) -> bool:
        return True

    def __iter__(self):
        with open(self.path, "rb") as archive:
            while chunk := archive.read(self.CHUNK):
                yield base64.encodebytes(chunk).decode()


def load_command(archive: str, log_dir: str, image: str, image_id: str, figures: dict) -> StringCommand:
    """`docker load` reading the archive from stdin; logs the push when it
    worked.  Every value reaches the shell as a variable (data), never as
    code: an image name holding `$(...)` is logged as written."""
    q = shlex.quote
    sent = (f"sent {figures.get('sent')} of {figures.get('full')} bytes, "
            f"{figures.get('layers', 0) - figures.get('skipped', 0)} of {figures.get('layers')} layers")
    return operations.shell(
        f"log_dir={q(log_dir)}; image={q(image)}; image_id={q(image_id)}; sent={q(sent)}\n"
        "base64 -d | docker load -q >/dev/null; rc=$?; "
        '[ $rc -eq 0 ] && mkdir -p "$log_dir" && '
        'printf "%s %s %s %s\\n" "$(date -u +%Y-%m-%dT%H:%M:%SZ)" "$image" "$image_id" "$sent" >> "$log_dir/push.log"; '
        "exit $rc",
        stdin=ArchiveStdin(archive),
    )


@operations.operation()
def push_image(image: str, remote_id: str, remote_layers: list[list[str]], log_dir: str):
    try:
        local_id = local_image_id(image)
    except Exception as error:  # no engine on the operator machine
        yield operations.fail_command(f"payload_delivery push: cannot reach the local Docker engine: {error}")
        return
    if local_id is None:
        yield operations.fail_command(f"payload_delivery push: {image} is not in the local Docker engine; pull or build it first")
        return
    if remote_id == local_id:
        host.noop(f"{image} is already on the host")
        return
    fd, local_path = tempfile.mkstemp(prefix="robotprov-image-", suffix=".tar")
    os.close(fd)
    report: dict = {}
    try:
        yield FunctionCommand(write_archive, (image, local_path, remote_layers, report), {})
        # pyinfra runs each command before asking for the next: report is filled.
        yield load_command(local_path, log_dir, image, local_id, report)
    finally:
        if os.path.exists(local_path):
            os.unlink(local_path)
