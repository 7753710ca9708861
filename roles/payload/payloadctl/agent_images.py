"""A pull robot's images put in place before its release runs, by the
command the payload's card names for the pull agent (``image_helper``):
``image-pull`` ahead of a window, ``image-load`` from a release on media.
Their arguments and exit statuses: docs/reference/payloadctl.md."""

import json
import os
import shutil
import subprocess

from . import imageref, images
from .system import Failure, log, run

NOT_HERE, TAMPERED = 3, 4  # what the agent reads (robotfleet/pull/robot/release_run.py)
MB = 1 << 20
PULL_TIMEOUT = 1800  # an image's pull, all tries


def docker(args, timeout):
    try:
        return run(["docker"] + args, check=False, timeout=timeout)
    except subprocess.TimeoutExpired:
        raise Failure(f"docker {args[0]} {args[-1]}: no answer within {timeout} s") from None
    except OSError as error:
        raise Failure(f"docker: {error}") from None


def said(done, otherwise):
    lines = [line.strip() for line in (done.stderr or done.stdout).splitlines() if line.strip()]
    return lines[-1][:300] if lines else otherwise


def pull(refs, docker_dir, min_free_mb):
    if shutil.which("docker") is None:
        return NOT_HERE
    for ref in refs:
        if images.image_info(ref) is not None:
            continue
        free = shutil.disk_usage(docker_dir).free if os.path.isdir(docker_dir) else None
        if free is not None and free < min_free_mb * MB:
            raise Failure(
                f"{ref}: only {free // MB} MB free on {docker_dir}'s file system (pull_min_free_mb: {min_free_mb})"
            )
        error = images.pull(ref, PULL_TIMEOUT, limit="the pull agent's limit")
        if error is not None:
            raise Failure("docker pull {}: {}".format(ref, error.splitlines()[-1]))
    return 0


def image_id(name):
    done = docker(["image", "inspect", "--format", "{{json .Id}}", name], 120)
    try:
        found = json.loads(done.stdout.strip().splitlines()[0]) if done.returncode == 0 else None
    except (ValueError, IndexError):
        return None
    return found if isinstance(found, str) else None


def load(ref, digest, image, archive=None):
    parsed = imageref.parse(ref)
    wanted = "{}@{}".format(parsed.repository, digest)
    tag = images.media_tag(wanted)
    if archive is None:
        return 0 if image_id(wanted) in (image, digest) or image_id(tag) == image else NOT_HERE
    done = docker(["load", "-q", "-i", archive], 1800)
    if done.returncode:
        raise Failure("docker load of {}: {}".format(ref, said(done, "exit status {}".format(done.returncode))))
    found = image_id(wanted)
    if found is None:  # the classic store: by the id it loaded, checked, then tagged by the digest
        found = image_id("{}:{}".format(parsed.repository, parsed.tag) if parsed.tag else image)
        if found == image:
            tagged = docker(["tag", image, tag], 120)
            if tagged.returncode or image_id(tag) != image:
                raise Failure("docker tag {} {}: {}".format(image, tag, said(tagged, "the tag does not name it")))
    if found not in (image, digest):
        log(f"{ref}: docker load gave {wanted} the id {found or 'none'}, the release binds {image}")
        return TAMPERED
    return 0


def command(work, *given):
    """``work(*given)``'s exit status; a failure's line on stderr."""
    try:
        return work(*given)
    except (Failure, ValueError, subprocess.TimeoutExpired) as error:
        log(str(error))
        return 1
