"""The Pythons of the platforms the tool supports, as this machine has them:
Ubuntu 20.04's 3.8, 22.04's 3.10 and 24.04's 3.12 (pyenv's builds here and
on CI, else the distribution's pythonX.Y), beside the main interpreter
(Debian 12's 3.11) and the lab robots' (Debian 13's 3.13).

A test that needs one and finds none fails, naming how to get it: this kind of
machine (and CI's) has them all.  ``ROBOT_TESTS_SKIP_MISSING=1`` skips such a
test instead, on a machine of another kind.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

RELEASES = {"3.8": "Ubuntu 20.04", "3.10": "Ubuntu 22.04", "3.12": "Ubuntu 24.04", "3.13": "Debian 13"}
ROBOT_PYTHONS = ("3.8", "3.10", "3.12")
OPERATOR_PYTHONS = ("3.10", "3.12")


def _patch_level(path: Path) -> int:
    found = re.fullmatch(r"\d+\.\d+\.(\d+)", path.parents[1].name)
    return int(found[1]) if found else -1


def find(version: str) -> Path | None:
    """The newest interpreter of ``version`` ("3.10") here, or None."""
    builds = Path(os.environ.get("PYENV_ROOT") or Path.home() / ".pyenv") / "versions"
    candidates = sorted(builds.glob(f"{version}.*/bin/python{version}"), key=_patch_level, reverse=True)
    candidates += [Path(f"/usr/bin/python{version}"), Path(f"/usr/local/bin/python{version}")]
    return next((path for path in candidates if path.is_file() and os.access(path, os.X_OK)), None)


def require(version: str) -> Path:
    """The interpreter of ``version``; the test fails without one (skip_or_fail)."""
    found = find(version)
    if found is None:
        skip_or_fail(
            f"no Python {version} ({RELEASES.get(version, 'another release')}'s) here: "
            f"pyenv install {version}, or the distribution's python{version}"
        )
    return found


def skip_or_fail(why: str) -> None:
    """Fail the test for a thing this machine lacks (skip it with ROBOT_TESTS_SKIP_MISSING=1)."""
    import pytest

    if os.environ.get("ROBOT_TESTS_SKIP_MISSING") == "1":
        pytest.skip(why)
    pytest.fail(why)


def as_system_python(python: Path) -> list[str]:
    """The argv prefix that runs a command with ``python`` as /usr/bin/python3
    (a bind mount in a mount namespace of its own: nothing changes outside
    it), as a robot of that release has it.  Needs root."""
    return ["unshare", "--mount", "sh", "-c", 'mount --bind "$0" /usr/bin/python3 && exec "$@"', str(python)]
