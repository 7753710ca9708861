"""Access to the outer Docker engine, starting dockerd when we may.

In CI a missing engine is a failure, never a skip: callers get LabError.
"""

from __future__ import annotations

import io
import os
import shutil
import socket
import subprocess
import tarfile
import time
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import docker

REPO_ROOT = Path(__file__).resolve().parents[2]
LAB_DIR = Path(os.environ.get("ROBOT_LAB_DIR", REPO_ROOT / ".lab")).resolve()
DOCKERD_LOG = LAB_DIR / "dockerd.log"
ENGINE_START_TIMEOUT_S = 60


class LabError(Exception):
    """An expected failure, reported to the user as one line."""


_client: docker.DockerClient | None = None


def client() -> docker.DockerClient:
    """A connected Docker client; starts dockerd if none answers and we can."""
    global _client
    if _client is not None:
        return _client
    found = _connect()
    if found is None:
        reason = _why_we_cannot_start_dockerd()
        if reason:
            raise LabError(f"no Docker engine and cannot start one: {reason}")
        _start_dockerd()
        found = _wait_for_engine(ENGINE_START_TIMEOUT_S)
    _client = found
    return found


def _connect() -> docker.DockerClient | None:
    # Imported on first use, not with this module: docker imports ssl, which
    # pyinfra's gevent must patch first when both share a process (unit tests).
    import docker

    try:
        c = docker.from_env(timeout=300)
        c.ping()
        return c
    except (docker.errors.DockerException, OSError):
        return None


def _os_ids() -> set[str]:
    ids: set[str] = set()
    try:
        text = Path("/etc/os-release").read_text()
    except OSError:
        return ids
    for line in text.splitlines():
        key, _, value = line.partition("=")
        if key in ("ID", "ID_LIKE"):
            ids.update(value.strip().strip('"').split())
    return ids


def _why_we_cannot_start_dockerd() -> str:
    docker_host = os.environ.get("DOCKER_HOST", "")
    if docker_host and docker_host != "unix:///var/run/docker.sock":
        return f"DOCKER_HOST={docker_host} does not answer"
    if os.geteuid() != 0:
        return "not root"
    if not _os_ids() & {"debian", "ubuntu"}:
        return "not Debian/Ubuntu"
    if shutil.which("dockerd") is None:
        return "dockerd is not installed (apt-get install docker.io)"
    return ""


def _start_dockerd() -> None:
    DOCKERD_LOG.parent.mkdir(parents=True, exist_ok=True)
    print(f"lab: no Docker engine answers; starting dockerd (log: {DOCKERD_LOG})")
    with open(DOCKERD_LOG, "ab") as log:
        # A new session so dockerd outlives us and our terminal.
        subprocess.Popen(
            ["dockerd"],
            stdout=log,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            start_new_session=True,
        )


def _wait_for_engine(timeout_s: float) -> docker.DockerClient:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        found = _connect()
        if found is not None:
            return found
        time.sleep(1)
    raise LabError(
        f"no Docker engine and cannot start one: dockerd did not answer within {timeout_s}s (see {DOCKERD_LOG})"
    )


class timed_phase:
    """Prints how long a phase of the lab took: `with timed_phase("start hosts"):`."""

    def __init__(self, name: str):
        self.name = name

    def __enter__(self):
        self.start = time.monotonic()
        print(f"lab: {self.name} ...", flush=True)
        return self

    def __exit__(self, exc_type, exc, tb):
        took = time.monotonic() - self.start
        outcome = "done" if exc_type is None else "FAILED"
        print(f"lab: {self.name}: {outcome} in {took:.1f}s", flush=True)
        return False


def get_or_none(collection, name: str):
    """collection.get(name) (containers, images, volumes), or None if absent."""
    import docker.errors

    try:
        return collection.get(name)
    except docker.errors.NotFound:
        return None


def published_ports(dc: docker.DockerClient) -> set[int]:
    """Host ports any container (running or not) publishes or asks for."""
    used: set[int] = set()
    for c in dc.containers.list(all=True):
        bindings = (c.attrs.get("HostConfig") or {}).get("PortBindings") or {}
        for entries in bindings.values():
            for entry in entries or ():
                if (entry.get("HostPort") or "").isdigit():
                    used.add(int(entry["HostPort"]))
    return used


def pick_free_port(start: int, avoid: set[int]) -> int:
    """The first port from `start` that nothing listens on and `avoid` lacks.

    Fixed ports (not Docker's random ones) keep a host's known_hosts entry
    valid across container restarts.
    """
    for port in range(start, start + 2000):
        if port in avoid:
            continue
        with socket.socket() as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
        return port
    raise LabError(f"no free 127.0.0.1 port in {start}..{start + 1999}")


def put_files(container, files: dict[str, str], mode: int = 0o644, owner: tuple[int, int] = (0, 0)) -> None:
    """Write text files (absolute paths) into a container, running or not.

    Parent directories must already exist in the container.
    """
    archive = io.BytesIO()
    with tarfile.open(fileobj=archive, mode="w") as tar:
        for path, text in files.items():
            data = text.encode()
            info = tarfile.TarInfo(path.lstrip("/"))
            info.size, info.mode = len(data), mode
            info.uid, info.gid = owner
            info.mtime = int(time.time())
            tar.addfile(info, io.BytesIO(data))
    if not container.put_archive("/", archive.getvalue()):
        raise LabError(f"could not write files into {container.name}")
