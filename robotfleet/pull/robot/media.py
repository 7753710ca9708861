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
checked as they are read), and the archive goes to the image helper a role
declared (agent.json's ``image_helper``: ``image-load REF DIGEST IMAGE_ID
ARCHIVE``), which loads it and checks that the image is then found by the
release's reference ``repository@digest`` with the id the release binds
(the payload's: roles/payload/payloadctl/agent_images.py).

The report goes to the remote as always; when the remote is out of reach it
is also written to the medium (``reports/<robot>.json``), and the agent
pushes it at its next contact (an unsent report is sent at the next wake).
"""

from __future__ import annotations

import os
import secrets
from pathlib import Path

from robotfleet.pull.protocol import media
from robotfleet.pull.robot.prepare import PrepareError


class MediaFailure(PrepareError):
    """The images could not be put in place here (one line); the release is
    tried again at the next wakes, as when it could not be prepared."""


def mounted(media_dir: str | None) -> Path | None:
    """The medium, when ``media_dir`` holds a release repository now."""
    if not media_dir:
        return None
    base = Path(media_dir)
    return base if (base / "metadata" / "timestamp.json").is_file() else None


def load_images(client, record, config, machine: str, work: Path) -> int:
    """Each image the release pins for ``config.robot`` in the engine, from
    the medium's archives, checked by the image helper a role declared
    (agent.json's ``image_helper``); how many were loaded.  refusals.Refused for
    a medium that is not what was signed, MediaFailure otherwise."""
    from robotfleet.pull.robot import refusals

    pins = record.images_of(config.robot)
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
        if _load(config, ref, pin, entry["image"]) == 0:
            continue  # already here, checked
        archive = client.download([entry["archive"]], work)[entry["archive"]]
        try:
            _load(config, ref, pin, entry["image"], str(archive))
        finally:
            archive.unlink(missing_ok=True)
        loaded += 1
    return loaded


def _load(config, *args: str) -> int:
    """The image helper's ``image-load``: 0 (here, checked) or NOT_HERE."""
    from robotfleet.pull.robot import refusals, release_run

    code, line = release_run.helper(config.image_helper, "image-load", *args)
    if code == release_run.TAMPERED:
        raise refusals.Refused(refusals.TAMPERED, line)
    if code not in (0, release_run.NOT_HERE):
        raise MediaFailure(line)
    return code


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
