"""The payload's part in a pull release (robotfleet publish): every image
of a host's compose project, resolved to the digest its registry gives now
(roles/payload/registry.py, with the fleet's insecure registries and each
registry's own credentials, roles/payload/credentials.py, as push delivery
reads it).  A reference already pinned by digest keeps its digest."""

from __future__ import annotations

import roles.docker.hooks as docker_hooks
import roles.payload.credentials as credentials
import roles.payload.digests as digests
import roles.payload.media_archive as media_archive
import roles.payload.payloadctl.imageref as imageref
import roles.payload.services as services
from robotfleet.role import PinPart

SETTING = digests.SETTING


def refs(data) -> list[str]:
    return services.images(data)


def resolve(data, wanted: list[str]) -> dict[str, str]:
    """ref -> "sha256:..." (the manifest or index the tag names now); ValueError with one line."""
    from roles.payload.registry import Registry, RegistryError

    found = {}
    for text in wanted:
        ref = imageref.parse(text)
        if ref.digest:
            found[text] = ref.digest
            continue
        try:
            own = credentials.lookup(data, ref.registry)  # this registry's, never another's
        except credentials.CredentialError as error:
            raise ValueError(f"image {text}: {error}") from None
        registry = Registry(ref.registry, docker_hooks.insecure_registries(data), own)
        try:
            _, _, digest = registry.manifest(ref.repository, ref.tag or "latest")
        except RegistryError as error:
            raise ValueError(f"image {text}: {error}") from None
        found[text] = digest
    return found


def archive(data, text: str, digest: str, machine: str, path) -> str:
    """The image as a `docker load` archive for robots of ``machine``
    (robotfleet export), read from its registry; its image id."""
    try:
        own = credentials.lookup(data, imageref.parse(text).registry)
    except credentials.CredentialError as error:
        raise ValueError(f"image {text}: {error}") from None
    return media_archive.write(text, digest, machine, path, docker_hooks.insecure_registries(data), own)


PINS = PinPart(refs=refs, resolve=resolve, setting=SETTING, archive=archive)
