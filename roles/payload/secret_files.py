"""The payload's secret files: what its containers read that the fleet file
must not hold (it travels to every robot and mirror in every release).

``payload_secret_files`` maps a name to a file on this machine (``/...`` or
``~/...``, outside the checkout); the fleet file holds only that path.  A
push deploy sends each file over SSH (stdin, as every file) to
``<payload_dir>/secrets/<name>`` on the robot, 0600 root:root in a 0700
directory, and every service gets it as a compose secret, read-only at
``/run/secrets/<name>``, unless the service lists its own ``secrets:``; a
service may read one as its ``env_file`` too.  Not in the release archive,
the compose file (it names the path) or the output (--diff says that a
secret file changes, not how; its content is masked like a password).

Compose binds the file when it creates a container: a changed file makes
the release run again with a restart, so the containers are created anew
with it.  A secret is not part of a release: a rollback keeps the current
file.  A pull robot's own run (the agent applying a release) sends nothing:
the file must already be there, placed by the push deploy that installed the
agent or by the image the robot boots from; a missing one fails that run in
one line.  A name dropped from the setting leaves its file on the robot (a
rollback to a release that used it still starts): delete it there.
"""

from __future__ import annotations

import os

import roles.payload.credentials as credentials
from robotfleet import CHECKOUT
from robotfleet import checkers as c
from robotfleet.host import operations
from robotfleet.host.snapshot import SnapshotQuery
from robotfleet.pull.protocol.agent_files import AGENT_RUN
from roles.payload.services import value_of

SETTING = "payload_secret_files"
NAME = r"[A-Za-z0-9][A-Za-z0-9_.-]*"
check = c.mapping_of(c.string(NAME, "a secret's name (letters, digits, _ . -)"), credentials.local_file)


class SecretFileError(Exception):
    """A secret file cannot be read here; the message is one line."""


def directory(payload_dir: str) -> str:
    return f"{payload_dir.rstrip('/')}/secrets"


def names(data) -> list[str]:
    return sorted(value_of(data, SETTING) or {})


def robot_path(data, name: str) -> str:
    return f"{directory(value_of(data, 'payload_dir'))}/{name}"


def top_level(data) -> dict:
    """The compose project's top-level ``secrets``: each name, its file on the robot."""
    return {"secrets": {name: {"file": robot_path(data, name)} for name in names(data)}} if names(data) else {}


def problems(data: dict) -> list[c.Problem]:
    """Before connecting: the files outside the checkout, and a service's
    own ``secrets:`` naming only secrets the setting declares."""
    found = [
        (
            f"{SETTING}.{c.key_name(name)}",
            f"{c.shown(path)} is inside the checkout {CHECKOUT}; keep secrets outside the repository "
            "(e.g. ~/.config/robotfleet/)",
        )
        for name, path in (data.get(SETTING) or {}).items()
        if isinstance(path, str) and credentials.inside_checkout(path)
    ]
    declared = set(names(data))
    for service, spec in (data.get("payload_services") or {}).items():
        listed = spec.get("secrets") if isinstance(spec, dict) else None
        for index, entry in enumerate(listed if isinstance(listed, list) else []):
            source = entry.get("source") if isinstance(entry, dict) else entry
            if isinstance(source, str) and source not in declared:
                found.append(
                    (
                        f"payload_services.{c.key_name(service)}.secrets[{index}]",
                        f"no secret {source!r} in {SETTING} (the robot has only those)",
                    )
                )
    return found


def read(data) -> dict[str, bytes]:
    """name -> the file's bytes, read on this machine; SecretFileError naming the setting and the file."""
    found = {}
    for name, path in sorted((data.get(SETTING) or {}).items()):
        local = os.path.expanduser(path)
        try:
            with open(local, "rb") as handle:
                found[name] = handle.read()
        except OSError as error:
            raise SecretFileError(
                f"{SETTING}.{name}: cannot read {local}: {error.strerror or error} (a file on this machine)"
            ) from None
    return found


def secrets(data) -> list[str]:
    """The files' contents, masked in output wherever they appear."""
    try:
        contents = read(data)
    except SecretFileError:
        return []
    return [text for text in (b.decode(errors="replace").strip("\r\n") for b in contents.values()) if text]


def declare_reads(data, query: SnapshotQuery) -> None:
    if names(data):
        query.files |= {directory(data.payload_dir), *(robot_path(data, name) for name in names(data))}


def place(data, snap) -> bool | None:
    """The secret files on the robot, sent from this machine: True when one
    changes (the release then runs again, its containers made anew), None
    when the host failed.  In a pull robot's own run they must be there."""
    if not names(data):
        return False
    if data.get(AGENT_RUN):
        for name in names(data):
            here = snap.files.get(robot_path(data, name))
            if here is None or here.kind != "file" or (here.mode, here.owner) != ("600", "root"):
                operations.fail(
                    name="Check the payload's secret files",
                    message=f"payload: {SETTING}.{name}: {robot_path(data, name)} is missing on this robot or "
                    "not a file of root with mode 0600; a release carries no secret: the push deploy that installs "
                    "the pull agent puts it there, or the image the robot boots from",
                )
                return None
        return False
    try:
        contents = read(data)
    except SecretFileError as error:
        operations.fail(name="Read the payload's secret files", message=f"payload: {error}")
        return None
    folder = directory(data.payload_dir)
    operations.directory(
        name=f"Payload secrets directory {folder}", path=folder, current=snap.files.get(folder), mode="0700"
    )
    changed = False
    for name, content in contents.items():
        path, current = robot_path(data, name), snap.files.get(robot_path(data, name))
        # Content, not mode: the containers bind the file, a chmod reaches them as it is.
        changed = changed or current is None or current.sha256 != operations.sha256(content)
        operations.file(
            name=f"Payload secret {name}", path=path, content=content, current=current, mode="0600", secret=True
        )
    return changed
