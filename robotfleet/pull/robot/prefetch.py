"""Prefetch: a release this robot will apply once its wave or maintenance
window opens is put in place now, so that the window holds only the switch.

When a check decides "waiting" (robotfleet/pull/robot/decide.py), the agent
asks ``ahead``: it downloads and verifies the code archive and the wheels
for this robot's platform (TUF targets, kept in the agent's targets
directory), unpacks and checks the tree (``code/<tree hash>``), makes the
venv, and has each of the robot's images pulled by the digest the record
names (``repo@sha256:...``) by the image helper a role declared
(agent.json's ``image_helper``, run as root: ``image-pull``), which skips
an image already present by that digest.  The check then reports
``prefetched``; the apply, when the gate opens, finds every target cached
(python-tuf's ``find_cached_target``), the tree and the venv made, and the
images present.

Once everything is in place, the release's switch is prepared, once a
release (``prepare_switch``; robotfleet/pull/robot/window_switch.py): when its plan
changes nothing but what runs, the window holds only the switch.

Nothing here touches what runs: the switch (``code/current``, ``venv``,
the payload) is the apply's alone.

An interrupted prefetch (no network, a reboot) is taken up again at the
next check where it stopped: targets already verified are kept whole, a
venv or tree already made is kept, an image already pulled is skipped, and
Docker keeps the layers of an interrupted pull.  That is a ``waiting``
check saying what is missing, never a failed release (nothing was tried).
Free disk is checked first (``pull_min_free_mb``, with the downloads the
release still needs, and again before each image).
"""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

# The downloads, and as much again twice: the unpacked tree and the venv's installed wheels.
UNPACKED_FACTOR = 3
PREFETCHED = "prefetched"
WAITING = "waiting"
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._/:-]{0,254}")
_DIGEST = re.compile(r"sha256:[0-9a-f]{64}")
MB = 1 << 20


class Incomplete(Exception):
    """What could not be had this time (one line): tried again at the next check."""


def by_digest(ref: str, digest: str) -> str:
    """``reg/ros/payload:1.1`` and its digest -> ``reg/ros/payload@sha256:...``
    (what Docker pulls and finds by the digest alone); ValueError naming a
    reference or digest that is neither."""
    name = ref.split("@", 1)[0]
    if name.rfind(":") > name.rfind("/"):
        name = name[: name.rfind(":")]
    if not _NAME.fullmatch(name) or not _DIGEST.fullmatch(digest or ""):
        raise ValueError(f"image {ref!r} -> {digest!r}: not an image reference and a sha256 digest")
    return f"{name}@{digest}"


def room(free: int, needed: int, min_free_mb: int, where: str) -> str | None:
    """Why ``needed`` bytes cannot be written where ``free`` bytes are free
    and ``min_free_mb`` must stay free; None when they can (pure)."""
    if free - needed >= min_free_mb * MB:
        return None
    return (
        f"it needs about {_mb(needed)} MB, {_mb(free)} MB are free on {where}'s file system "
        f"(pull_min_free_mb: {min_free_mb})"
    )


def _mb(size: int) -> int:
    return -(-size // MB)


def free_on(path: str) -> int | None:
    return shutil.disk_usage(path).free if os.path.isdir(path) else None


def ahead(wake, client, waiting) -> tuple[str, str, str | None]:
    """(result, reason, refusal) of a check whose ``waiting`` decision leaves
    time: ``prefetched`` once everything is in place, else ``waiting`` with
    what is missing, or ``refused`` for a target or tree that is not what
    the record binds (the apply would refuse it the same way).  ``wake``:
    the agent's Wake (record, config, state); ``client``: its TUF client."""
    from robotfleet.pull.robot import prepare, refusals

    record, config, state_dir = wake.record, wake.config, wake.state_dir
    version = record.version
    done = wake.state.get("prefetched") or {}
    if done.get("version") == version and all(Path(p).exists() for p in done.get("paths", [])):
        prepare_switch(wake, done)
        return PREFETCHED, _said(done, waiting.reason), None
    try:
        found = _targets(record, client, state_dir, config.min_free_mb)
        paths = [str(prepare.code_dir(state_dir, record, found[record.code]))]
        wheels = {p: found[p] for p in found if p != record.code}
        if wheels:
            paths.append(str(prepare.venv_for(state_dir, wheels)))
        images = pull_images(record.images_of(config.robot), config)
    except refusals.Refused as refused:
        if refused.reason != refusals.UNAVAILABLE:
            return "refused", refused.line, refused.reason
        return WAITING, f"release {version} not prefetched yet: {refused.line}; {waiting.reason}", None
    except prepare.Mismatch as error:
        return "refused", f"release {version}: {error}", refusals.TAMPERED
    except (Incomplete, prepare.PrepareError, OSError) as error:
        return WAITING, f"release {version} not prefetched yet: {error}; {waiting.reason}", None
    wake.state["prefetched"] = done = {
        "version": version,
        "paths": paths,
        "wheels": len(wheels),
        "images": None if images is None else len(images),
    }
    prepare_switch(wake, done)
    return PREFETCHED, _said(done, waiting.reason), None


def prepare_switch(wake, done: dict) -> None:
    """The release's switch prepared for its window, once (``done["switch"]``:
    what was prepared, or why the window runs the whole converge)."""
    if "switch" in done or done.get("images") is None:
        return
    import secrets

    from robotfleet.pull.robot import release_run

    robot = wake.config.robot
    code = Path(done["paths"][0])
    venv = Path(done["paths"][1]) if len(done["paths"]) > 1 else Path(os.path.realpath(wake.state_dir / "venv"))
    deployment = f"pull-{robot}-{done['version']}-{secrets.token_hex(3)}"  # the window's, named now
    said = release_run.converge(wake.state_dir, wake.record, robot, code, venv, "prepare", deployment)
    prepared = said.get("prepared")
    done["switch"] = prepared if isinstance(prepared, dict) else {"why": str(said.get("why") or said.get("error"))}


def _said(done: dict, waiting: str | None) -> str:
    images = "no Docker yet: images at the apply" if done.get("images") is None else f"{done['images']} image(s)"
    switch = done.get("switch") or {}
    ready = ", its switch prepared" if switch.get("target") else ""
    if switch.get("why"):
        ready = f", its window runs the whole converge: {switch['why'][:160]}"
    return f"release {done['version']} prefetched (code, {done.get('wheels', 0)} wheel(s), {images}{ready}); {waiting}"


def _targets(record, client, state_dir: Path, min_free_mb: int) -> dict[str, Path]:
    """The code archive and this platform's wheels, verified, into the
    agent's targets directory (kept if already there and verified)."""
    from robotfleet.pull.protocol import platforms

    wanted = [record.code, *record.wheels_for(platforms.platform_key())]
    directory = state_dir / "targets"
    missing = 0
    for path in wanted:
        info = client.updater.get_targetinfo(path) if client.updater else None
        if info is not None and not (directory / path).is_file():
            missing += info.length
    why = room(free_on(str(state_dir)) or 0, missing * UNPACKED_FACTOR, min_free_mb, str(state_dir))
    if why:
        raise Incomplete(why)
    return client.download(wanted, directory)


def pull_images(images: dict[str, str], config) -> list[str] | None:
    """Each image by its digest, present afterwards, pulled by the image
    helper a role declared (agent.json's ``image_helper``); the references
    (None: no Docker or no helper on the robot yet, which the release's own
    converge installs: its images are pulled then).  Incomplete at the
    first that cannot be had (the rest: the next check)."""
    from robotfleet.pull.robot import release_run

    wanted = []
    for ref, digest in sorted(images.items()):
        try:
            wanted.append(by_digest(ref, digest))
        except ValueError as error:
            raise Incomplete(str(error)) from None
    if not wanted:
        return wanted
    free = ("--docker-dir", config.docker_dir, "--min-free-mb", str(config.min_free_mb))
    code, line = release_run.helper(config.image_helper, "image-pull", *free, *wanted)
    if code in (None, release_run.NOT_HERE):
        return None
    if code:
        raise Incomplete(line)
    return wanted
