"""The release's images on this robot: pulled (bounded, while the old
release keeps running) or already pushed, checked against this robot's
platform, then pinned by digest.

A release on removable media (docs/guides/pull.md) arrives by ``docker load``
(agent_images.py, run by the pull agent), each loaded image's id checked
against the signed release; where Docker cannot find it by the release's
digest (the classic image store keeps no registry digest for a loaded
image) that id is tagged
``repository:media-sha256-<the digest's hex>`` (MEDIA_TAG): such an image
runs by that tag, named by the digest it was checked against."""

import json
import subprocess
import time

from . import imageref, platforms
from .system import Failure, Refusal, run

MEDIA_TAG = "media-sha256-"


def image_info(ref):
    proc = run(["docker", "image", "inspect", ref], check=False, timeout=60)
    if proc.returncode != 0:
        return None
    data = json.loads(proc.stdout)[0]
    platform = {"os": data.get("Os") or "linux", "architecture": data.get("Architecture") or ""}
    if data.get("Variant"):
        platform["variant"] = data["Variant"]
    return {"id": data["Id"], "repo_digests": data.get("RepoDigests") or [], "platform": platform}


def engine():
    """(architecture, version) of this robot's Docker engine, one `docker
    version`: the architecture as it runs images (an armhf userland on an
    arm64 kernel runs arm images), else as dpkg says; the version "" when
    the engine does not say."""
    proc = run(["docker", "version", "-f", "{{.Server.Arch}} {{.Server.Version}}"], check=False, timeout=60)
    arch, _, version = (proc.stdout.strip() if proc.returncode == 0 else "").partition(" ")
    if not arch:
        proc = run(["dpkg", "--print-architecture"], check=False, timeout=60)
        arch = proc.stdout.strip() if proc.returncode == 0 else ""
    return platforms.go_arch(arch), version.strip()


def check_platform(ref, info, robot, arch):
    """Refuse, before anything switches, an image this robot cannot run."""
    if arch and not platforms.matches(arch, info["platform"]):
        raise Refusal(platforms.refusal(robot, arch, ref, [platforms.text(info["platform"])]))


def pull(ref, timeout, platform=None, limit="payload_pull_timeout"):
    """docker pull, three tries, all within `timeout` seconds (``limit``
    names what sets it); the error text."""
    deadline = time.time() + timeout
    last = ""
    for attempt in range(3):
        time.sleep(min(2 * attempt, max(0, deadline - time.time())))
        left = deadline - time.time()
        if left <= 0:
            break
        try:
            proc = run(
                ["docker", "pull", "-q"] + (["--platform", platform] if platform else []) + [ref],
                check=False,
                timeout=left,
            )
        except subprocess.TimeoutExpired:
            raise Failure(
                f"docker pull {ref} did not finish within {timeout} s ({limit}); the old release keeps running"
            ) from None
        if proc.returncode == 0:
            return None
        last = (proc.stderr or proc.stdout).strip()[-300:]
    return last or "gave up after {} s ({})".format(timeout, limit)


def media_tag(ref):
    """The tag the pull agent gives an image of a release on media, checked
    against the digest ``ref`` names (None: ``ref`` names none)."""
    parsed = imageref.parse(ref)
    if not parsed.digest:
        return None
    return "{}:{}{}".format(parsed.repository, MEDIA_TAG, parsed.digest.split(":", 1)[1])


def already_here(ref):
    """The image ``ref`` names by its digest, when this robot has it: found
    by that digest (as a pull, or the containerd store's load of a release
    on media, left it), or by the tag the pull agent gave the id it checked
    (a release on media, on the classic store); else None.  What a digest
    names never changes, so it is not pulled again."""
    tag = media_tag(ref)
    if tag is None:
        return None
    info = image_info(ref)
    if info is not None:
        return info
    info = image_info(tag)
    return dict(info, media=tag) if info else None


def obtain(ref, delivery, pull_timeout, platform=None):
    """Make the image present, pulling while the old release keeps running
    (Docker picks the robot's variant of a multi-platform image, or
    ``platform`` where the service pins one; such a service is always
    pulled: the digest of an index already here may be another variant).
    An image already here by the digest its reference names is that image
    (a pull robot's prefetch, or a release on media, brought it): not
    pulled again, so the window holds only the switch."""
    here = already_here(ref) if delivery == "pull" and not platform else None
    if here is not None:
        return here
    if delivery == "pull":
        error = pull(ref, pull_timeout, platform)
        if error is not None and image_info(ref) is None:
            raise Failure("cannot pull {}: {}; the old release keeps running".format(ref, error))
    info = image_info(ref)
    if info is None:
        raise Failure("image {} is not on this robot (delivery: {})".format(ref, delivery))
    return info


def pinned(ref, info):
    """``ref`` by the digest its registry gave, where it gave one; a
    reference that names its own digest (a signed pull release) keeps that
    one, whatever other digests the same image was also pulled under."""
    repo = imageref.repository(ref)
    own = imageref.parse(ref).digest
    if own and info.get("media"):
        return info["media"]
    if own:
        return "{}@{}".format(repo, own)
    for digest_ref in info["repo_digests"]:
        if imageref.repository(digest_ref) == repo:
            return digest_ref
    return ref
