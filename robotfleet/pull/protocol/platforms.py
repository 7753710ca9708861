"""A robot's platform as a release names it: ``cp<major><minor>-<machine>``
(cp313-x86_64, cp311-aarch64: the robot's python and ``uname -m``), whose
wheels the release carries (the operator fetches them, the robot installs
the ones of its own platform)."""

from __future__ import annotations

import os
import re
import sys

_PLATFORM = re.compile(r"cp3([0-9]{1,2})-(x86_64|aarch64|armv7l)")


def platform_key(version: tuple[int, int] | None = None, machine: str | None = None) -> str:
    """This interpreter's platform (or the one given): 'cp313-x86_64'."""
    major, minor = version or sys.version_info[:2]
    machine = machine or os.uname().machine
    return f"cp{major}{minor}-{ {'amd64': 'x86_64', 'arm64': 'aarch64'}.get(machine, machine) }"


def parse_platform(key: str) -> tuple[str, str]:
    """'cp313-x86_64' -> ('3.13', 'x86_64'); ValueError with one line otherwise."""
    match = _PLATFORM.fullmatch(str(key))
    if not match:
        raise ValueError(
            f"platform {key!r}: expected cp<python version>-<machine>, e.g. cp313-x86_64 or "
            "cp311-aarch64 (machines: x86_64, aarch64, armv7l)"
        )
    return f"3.{match.group(1)}", match.group(2)
