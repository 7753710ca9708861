"""payload_delivery push: who a push is for, and the images beyond the
first (the first one's push is in steps.py): what the snapshot reads of
them and each one the robot lacks sent over SSH."""

from __future__ import annotations

import shlex

from pyinfra import host

import roles.docker.hooks as docker_hooks
import roles.payload.image_transfer as image_transfer
import roles.payload.payloadctl.imageref as imageref
import roles.payload.services as services
from robotfleet.host.snapshot import Snapshot, SnapshotQuery
from roles.payload.credentials import registry_key


def declare_reads(data, query: SnapshotQuery) -> None:
    if data.payload_delivery == "push":
        for index, ref in enumerate(more_images(data)):
            query.probes[f"payload_image_id_{index + 1}"] = image_id_probe(ref)


def more_images(data) -> list[str]:
    """Images beyond the first (whose push the single-image code does)."""
    return services.images(data)[1:]


def image_id_probe(ref: str) -> str:
    return f"docker image inspect -f '{{{{.Id}}}}' {shlex.quote(ref)}"


def push_target(data, snap: Snapshot, credentials) -> dict:
    """Who a push is for: the robot, its architecture (from the snapshot),
    and how to read the image's registry for its own variant."""
    return {
        "robot": host.name,
        "arch": snap.arch,
        "insecure": docker_hooks.insecure_registries(data),
        "credentials": credentials,
    }


def push_more_images(data, snap: Snapshot, auths: dict | None = None) -> None:
    """payload_delivery push for a project of several images: each one the
    robot lacks is sent (layers the robot has are left out, as for the
    first), read from its registry with that registry's own credentials
    (``auths``: registry -> Credentials or None)."""
    if data.payload_delivery != "push":
        return
    layers = image_transfer.parse_layer_sets(snap.probes.get("docker_layers", ""))
    for index, ref in enumerate(more_images(data)):
        credentials = (auths or {}).get(registry_key(imageref.parse(ref).registry))
        image_transfer.push_image(
            name=f"Send the payload image {ref} over SSH",
            image=ref,
            remote_id=snap.probes.get(f"payload_image_id_{index + 1}", "").strip(),
            remote_layers=layers,
            log_dir=data.payload_dir,
            **push_target(data, snap, credentials),
        )
