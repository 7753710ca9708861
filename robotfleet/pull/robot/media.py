"""A release from removable media or a LAN share (``robotfleet export``), on
the robot.

The agent's ``media_dir`` (the host's ``pull_media_dir``: where a USB
stick or an NFS share is mounted) is looked at each wake; when it holds a
release repository (``metadata/timestamp.json``), that directory is
verified by the same TUF refresh (robotfleet/pull/robot/verify.py):
tampered, replayed, expired and foreign-signed media are refused exactly as
over the network.  The fleet remote is still fetched: when it answers, both
are verified from the same trusted state and the newer signed record is the
wake's (verify.newest: the medium on the same version, a halt on the same
version first), so a stale medium never pins the robot nor hides a halt;
when it does not, the medium alone is.

To apply, each image the release pins for this robot comes from the media:
``media.json`` and the image's archive are TUF targets (length and sha256
checked as they are read), the archive goes to ``docker load``, and the
image must then be found by the release's reference ``repository@digest``
with the id the release binds: the containerd image store keeps the
registry digest of the archive's OCI index (its image id is that digest).
The classic store keeps only the image id (the config's digest) and cannot
find an image by a registry digest it never pulled: there the loaded
image's id is checked against the one the release binds, and that id is
tagged ``repository:media-sha256-<the pin's hex>`` (protocol/media.py
MEDIA_TAG), the name the payload runs it by (payloadctl/images.py).

The report goes to the remote as always; when the remote is out of reach it
is also written to the medium (``reports/<robot>.json``), and the agent
pushes it at its next contact (an unsent report is sent at the next wake).
"""

from __future__ import annotations

import json
import os
import secrets
import subprocess
from pathlib import Path

from robotfleet.pull.protocol import media
from robotfleet.pull.robot.prepare import PrepareError

DOCKER_ENV = "ROBOTFLEET_DOCKER"  # the docker program (tests give one that records its calls)
DOCKER_TIMEOUT = 1800


class MediaFailure(PrepareError):
    """The images could not be put in place here (one line); the release is
    tried again at the next wakes, as when it could not be prepared."""


def mounted(media_dir: str | None) -> Path | None:
    """The medium, when ``media_dir`` holds a release repository now."""
    if not media_dir:
        return None
    base = Path(media_dir)
    return base if (base / "metadata" / "timestamp.json").is_file() else None


def split_ref(ref: str) -> tuple[str, str | None]:
    """An image reference as a release names it -> (repository, tag or None)."""
    name = ref.split("@", 1)[0]
    slash, colon = name.rfind("/"), name.rfind(":")
    return (name[:colon], name[colon + 1 :]) if colon > slash else (name, None)


def digest_ref(ref: str, digest: str) -> str:
    """``ref``'s repository at ``digest``: what the payload runs."""
    return f"{split_ref(ref)[0]}@{digest}"


def tag_ref(ref: str) -> str | None:
    repository, tag = split_ref(ref)
    return f"{repository}:{tag}" if tag else None


def media_tag(ref: str, digest: str) -> str:
    return f"{split_ref(ref)[0]}:{media.MEDIA_TAG}{digest.split(':', 1)[1]}"


def docker(*args: str, timeout: int = 120) -> subprocess.CompletedProcess:
    program = os.environ.get(DOCKER_ENV) or "docker"
    try:
        return subprocess.run([program, *args], capture_output=True, text=True, timeout=timeout, check=False)
    except (OSError, subprocess.TimeoutExpired) as error:
        raise MediaFailure(f"docker {args[0]}: {error}") from None


def image_id(name: str) -> str | None:
    """The id of image ``name`` in the robot's Docker engine, or None."""
    done = docker("image", "inspect", "--format", "{{json .Id}}", name)
    if done.returncode:
        return None
    try:
        found = json.loads(done.stdout.strip().splitlines()[0])
    except (ValueError, IndexError):
        return None
    return found if isinstance(found, str) else None


def load_images(client, record, robot: str, machine: str, work: Path) -> int:
    """Each image the release pins for ``robot`` in the engine, from the
    medium's archives, checked; how many were loaded.  refusals.Refused for
    a medium that is not what was signed, MediaFailure otherwise."""
    from robotfleet.pull.robot import refusals

    pins = record.images_of(robot)
    if not pins:
        return 0
    index_file = client.download([media.NAME], work)[media.NAME]
    try:
        index = media.parse(index_file.read_bytes())
    except media.MediaError as error:
        raise refusals.Refused(refusals.MALFORMED, str(error)) from None
    if index["version"] != record.version:
        raise refusals.Refused(
            refusals.MALFORMED, f"{media.NAME}: for release {index['version']}, not release {record.version}"
        )
    mine = index["images"].get(machine, {})
    loaded = 0
    for ref, pin in sorted(pins.items()):
        entry = mine.get(ref)
        if entry is None or entry["digest"] != pin:
            raise refusals.Refused(refusals.MALFORMED, f"{media.NAME}: no archive of {ref}@{pin} for {machine}")
        wanted, tag = digest_ref(ref, pin), media_tag(ref, pin)
        if image_id(wanted) in (entry["image"], pin) or image_id(tag) == entry["image"]:
            continue  # already here, checked
        archive = client.download([entry["archive"]], work)[entry["archive"]]
        try:
            done = docker("load", "-q", "-i", str(archive), timeout=DOCKER_TIMEOUT)
        finally:
            archive.unlink(missing_ok=True)
        if done.returncode:
            said = (done.stderr or done.stdout).strip().splitlines() or [f"exit status {done.returncode}"]
            raise MediaFailure(f"docker load of {ref}: {said[-1][:300]}")
        found = image_id(wanted)
        if found is None:  # the classic store: by the id it loaded, checked, then tagged by the digest
            found = image_id(tag_ref(ref) or entry["image"])
            if found == entry["image"]:
                tagged = docker("tag", entry["image"], tag)
                if tagged.returncode or image_id(tag) != entry["image"]:
                    said = (tagged.stderr or tagged.stdout).strip().splitlines() or ["the tag does not name it"]
                    raise MediaFailure(f"docker tag {entry['image']} {tag}: {said[-1][:300]}")
        if found not in (entry["image"], pin):
            raise refusals.Refused(
                refusals.TAMPERED,
                f"{ref}: docker load gave {wanted} the id {found or 'none'}, the release binds {entry['image']}",
            )
        loaded += 1
    return loaded


def write_report(medium: Path, robot: str, data: bytes) -> str:
    """The report written back to the medium (a temp file, then renamed; the
    medium is not trusted: its reports/ is never followed as a link, nor the
    file's name); what happened, for the journal line."""
    directory = medium / media.REPORTS
    try:
        try:
            os.mkdir(directory, 0o755)
        except FileExistsError:
            pass
        fd = os.open(directory, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW)
    except OSError as error:
        return f"not written to the medium either ({directory}: {error.strerror or error})"
    temp = f".{robot}.json.{secrets.token_hex(4)}"
    try:
        out = os.open(temp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o644, dir_fd=fd)
        with os.fdopen(out, "wb") as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        os.rename(temp, f"{robot}.json", src_dir_fd=fd, dst_dir_fd=fd)
        os.fsync(fd)
    except OSError as error:
        try:
            os.unlink(temp, dir_fd=fd)
        except OSError:
            pass
        return f"not written to the medium either ({error.strerror or error})"
    finally:
        os.close(fd)
    return f"written to {directory / (robot + '.json')}"
