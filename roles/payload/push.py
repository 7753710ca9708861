"""payload_delivery: push — the image comes from the operator machine's Docker
engine (Docker SDK for Python) over the existing SSH connection, only when
the robot does not already have that exact image."""

from __future__ import annotations

import os
import shlex
import tempfile

from pyinfra import host
from pyinfra.api import FileUploadCommand, FunctionCommand

from roles import remote


def local_image_id(image: str) -> str | None:
    import docker

    try:
        return docker.from_env().images.get(image).id
    except docker.errors.ImageNotFound:
        return None


def save_image(image: str, path: str) -> None:
    import docker

    with open(path, "wb") as handle:
        for chunk in docker.from_env().images.get(image).save(named=True):
            handle.write(chunk)


@remote.operation()
def push_image(image: str, remote_id: str):
    try:
        local_id = local_image_id(image)
    except Exception as error:  # no engine on the operator machine
        yield remote.fail_command(f"payload_delivery push: cannot reach the local Docker engine: {error}")
        return
    if local_id is None:
        yield remote.fail_command(f"payload_delivery push: {image} is not in the local Docker engine; pull or build it first")
        return
    if remote_id == local_id:
        host.noop(f"{image} is already on the host")
        return
    fd, local_path = tempfile.mkstemp(prefix="robotprov-image-", suffix=".tar")
    os.close(fd)
    remote_path = f"/tmp/robotprov-image-{local_id.split(':')[-1][:16]}.tar"
    yield FunctionCommand(save_image, (image, local_path), {})
    yield FileUploadCommand(local_path, remote_path, _sudo=False)
    yield FunctionCommand(os.unlink, (local_path,), {})
    yield remote.shell(f"docker load -q -i {shlex.quote(remote_path)} >/dev/null; rc=$?; rm -f {shlex.quote(remote_path)}; exit $rc")
