"""The payload's part in a pull release (robotfleet publish): every image
of a host's compose project, resolved to the digest its registry gives now
(roles/payload/registry.py, with the fleet's insecure registries and the
registry credentials' environment variables, as push delivery reads it).
A reference already pinned by digest keeps its digest."""

from __future__ import annotations

import os

from robotfleet.role import PinPart
import roles.payload.services as services
import roles.payload.payloadctl.imageref as imageref

SETTING = "payload_image_pins"


def refs(data) -> list[str]:
    return services.images(data)


def resolve(data, wanted: list[str]) -> dict[str, str]:
    """ref -> "sha256:..." (the manifest or index the tag names now); ValueError with one line."""
    from roles.payload.registry import Registry, RegistryError

    username = os.environ.get(data.payload_registry_username_env or "")
    password = os.environ.get(data.payload_registry_password_env or "")
    credentials = (username, password) if username and password else None
    found = {}
    for text in wanted:
        ref = imageref.parse(text)
        if ref.digest:
            found[text] = ref.digest
            continue
        registry = Registry(ref.registry, list(data.docker_insecure_registries or []), credentials)
        try:
            _, _, digest = registry.manifest(ref.repository, ref.tag or "latest")
        except RegistryError as error:
            raise ValueError(f"image {text}: {error}") from None
        found[text] = digest
    return found


PINS = PinPart(refs=refs, resolve=resolve, setting=SETTING)
