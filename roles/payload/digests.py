"""The digests a signed pull release binds (``payload_image_pins``: image
reference as the fleet file writes it -> "sha256:..."), applied to the
compose project, and what is refused with them (pure).

A pinned image runs as ``repository:tag@digest``: Docker pulls and finds it
by the digest alone (the tag is ignored where a digest is given), and the
robot's release record, keyed by the reference, still shows the version.
Pins bind a release whole or not at all: an image the pins leave out would
run whatever its tag names today, next to pinned ones (the mix-and-match a
signed release exists to prevent)."""

from __future__ import annotations

import roles.payload.payloadctl.imageref as imageref
import roles.payload.services as services
from robotfleet.checkers import key_name

SETTING = "payload_image_pins"
DIGEST = r"sha256:[a-f0-9]{64}"


def given(data) -> dict[str, str]:
    """The host's pins ({} when none are given)."""
    pins = services.value_of(data, SETTING)
    return pins if isinstance(pins, dict) else {}


def pinned(ref, pins: dict[str, str]):
    """``ref`` as the release binds it (repository[:tag]@digest), or
    unchanged where ``pins`` names no digest for it."""
    digest = pins.get(ref) if isinstance(ref, str) else None
    if digest is None:
        return ref
    try:
        parsed = imageref.parse(ref)
    except ValueError:  # refused by the image's own check
        return ref
    return str(imageref.ImageRef(parsed.repository, parsed.tag, digest))


def runs(running: str, wanted: str) -> bool:
    """Whether a release that runs ``running`` (the reference its record is
    keyed by, as the compose project named it) runs the image ``wanted``:
    the same repository and, where ``wanted`` names a digest (a release's
    pin), that digest, the tag being only its name for people; else the
    same tag (a digest ``running`` adds is that tag as it was resolved)."""
    if running == wanted:
        return True
    try:
        have, want = imageref.parse(running), imageref.parse(wanted)
    except ValueError:
        return False
    if have.repository != want.repository:
        return False
    if want.digest:
        return have.digest == want.digest
    return have.tag == want.tag


def shown(ref: str, pinned: str | None) -> str:
    """What a robot runs, for people: ``ref`` (the record's key, with its
    tag) with the digest it runs by (``pinned``: payloadctl's reference by
    digest, which Docker names without the tag), e.g. ``reg/p:2@sha256:...``."""
    try:
        named, by_digest = imageref.parse(ref), imageref.parse(pinned) if pinned else None
    except ValueError:
        return pinned or ref
    digest = named.digest or (by_digest.digest if by_digest and by_digest.repository == named.repository else None)
    return str(imageref.ImageRef(named.repository, named.tag, digest))


def images(data) -> list[str]:
    """Every image the host's project runs, as it runs them (pins applied)."""
    pins = given(data)
    return [pinned(ref, pins) for ref in services.images(data)]


def problems(data) -> list[tuple[str, str]]:
    """The pins against the host's project: (field, one line) each."""
    pins = given(data)
    if not pins:
        return []
    if services.value_of(data, "payload_delivery") == "push":
        return [
            (
                SETTING,
                "pins need payload_delivery: pull: a pushed image arrives by docker load, which keeps "
                "its image id but not the registry digest a release pins, so the robot could not "
                "run it by that digest",
            )
        ]
    found = []
    refs = services.images(data)
    missing = [ref for ref in refs if ref not in pins]
    if missing:
        found.append(
            (
                SETTING,
                f"no digest for {', '.join(missing)}: the pins must cover every image of the "
                f"project ({len(refs)} here), or that image would run whatever its tag names now",
            )
        )
    for ref in refs:
        own = _own_digest(ref)
        if own and ref in pins and pins[ref] != own:
            found.append(
                (f"{SETTING}.{key_name(ref)}", f"{pins[ref]} differs from the digest the image names itself ({own})")
            )
    return found


def _own_digest(ref: str) -> str | None:
    try:
        return imageref.parse(ref).digest
    except ValueError:
        return None
