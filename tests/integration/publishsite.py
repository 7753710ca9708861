"""An operator's deploy repository for the pull commands (publish, halt,
keys, export), as tests/integration/test_pull_publish.py and the media
tests use it: the checkout with what a robot needs of it and a fleet file
(FLEET), its own remote and a bare releases remote, the fleet's keys
(robotfleet keys init), the payload's tags in an OCI registry answering
the manifest requests (tests/unit/pullkit.py's Registry), and a robot's
shallow copy of the releases branch.  tests/integration/conftest.py's
``site`` and ``registry`` fixtures make them."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import robotfleet
from robotfleet.pull.protocol.tree import DEPLOY_PATHS

FLEET = """\
all:
  vars:
    payload_image: {registry}/ros/payload:1.1
robots:
  vars:
    pull_enabled: true
    pull_remote: https://git.example.com/fleet.git
  hosts:
    robot1: {{address: 127.0.0.1}}
    robot2: {{address: 127.0.0.1, payload_image: "{registry}/ros/payload:1.2", pull_interval: 1000}}
    robot3: {{address: 127.0.0.1, pull_enabled: false}}
"""


def git(where, *args) -> str:
    return subprocess.run(
        ["git", "-C", str(where), "-c", "user.name=op", "-c", "user.email=op@x", *args],
        check=True,
        capture_output=True,
        text=True,
    ).stdout.strip()


def robotfleet_cmd(*args, env=None, check=True) -> subprocess.CompletedProcess:
    done = subprocess.run(
        [sys.executable, "-m", "robotfleet", *map(str, args)],
        capture_output=True,
        text=True,
        env={**os.environ, **(env or {})},
        timeout=600,
    )
    if check and done.returncode:
        raise AssertionError(f"robotfleet {args[0]} exited {done.returncode}: {done.stderr}")
    return done


def site(tmp_path: Path, registry) -> dict:
    """A deploy repository pushed to a bare remote, keys, and a robot's directory."""
    checkout = tmp_path / "deploy"
    checkout.mkdir()
    for name in DEPLOY_PATHS:  # what a robot needs of a checkout, as publish takes it
        source = robotfleet.CHECKOUT / name
        if source.is_dir():
            shutil.copytree(source, checkout / name, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy(source, checkout / name)
    (checkout / "inventories" / "robots.yaml").write_text(FLEET.format(registry=registry.address))
    git(tmp_path, "init", "-q", "-b", "main", str(checkout))
    git(checkout, "add", "-A")
    git(checkout, "commit", "-qm", "fleet")
    origin = tmp_path / "deploy.git"  # the deploy repository's own remote, kept apart from the releases
    git(tmp_path, "init", "-q", "--bare", str(origin))
    git(checkout, "remote", "add", "origin", str(origin))
    git(checkout, "push", "-q", "origin", "main")
    remote = tmp_path / "remote.git"  # the fleet's releases remote, named once in the checkout's git config
    git(tmp_path, "init", "-q", "--bare", str(remote))
    git(checkout, "config", "robotfleet.remote", str(remote))
    registry.tag("ros/payload", "1.1", "one")
    registry.tag("ros/payload", "1.2", "two")
    keys = tmp_path / "keys"
    robotfleet_cmd("keys", "init", "--keys", keys)
    return {
        "checkout": checkout,
        "remote": remote,
        "origin": origin,
        "keys": keys,
        "robot": tmp_path / "robot",
        "base": tmp_path,
    }


def robot_fetch(site) -> Path:
    """The robot's copy of the releases branch (fetched shallow, as the agent does)."""
    copy = site["robot"] / "releases"
    if not copy.exists():
        git(
            site["base"],
            "clone",
            "-q",
            "--depth",
            "1",
            "--branch",
            "robotfleet/releases",
            f"file://{site['remote']}",
            str(copy),
        )
    else:
        git(copy, "fetch", "-q", "--depth", "1", "origin", "robotfleet/releases")
        git(copy, "reset", "-q", "--hard", "FETCH_HEAD")
    return copy
