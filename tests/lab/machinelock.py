"""Locks shared by every lab on this machine (every checkout: the Docker
engine and its images are the machine's), so labs started at once build
each image tag once and never pick the same port.

    with machine_lock(f"image {tag}"):
        ...  # check again whether the image exists, then build it
"""

from __future__ import annotations

import fcntl
import os
import re
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

PORTS_LOCK = "ports"  # held from picking a free port to creating the container that publishes it
LOCK_DIR = Path(os.environ.get("ROBOT_LAB_LOCK_DIR", Path(tempfile.gettempdir()) / "robot-lab-locks"))


def lock_path(name: str) -> Path:
    """The lock file of ``name`` (an image tag, "ports"): one safe file name."""
    return LOCK_DIR / (re.sub(r"[^A-Za-z0-9_.-]", "_", name) + ".lock")


@contextmanager
def machine_lock(name: str):
    """Hold the machine-wide lock ``name``; says so when another lab holds it."""
    path = lock_path(name)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a") as lock:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            started = time.monotonic()
            print(f"lab: waiting for another lab's {name} ...", flush=True)
            fcntl.flock(lock, fcntl.LOCK_EX)
            print(f"lab: waited {time.monotonic() - started:.1f}s for another lab's {name}", flush=True)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)
