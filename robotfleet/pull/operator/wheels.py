"""The wheelhouse robots install their venv from (the agent's, pyinfra's):
binary wheels only, fetched on the operator's side for each robot platform
with ``pip download --only-binary=:all:``, so a robot never needs an index.

A platform is ``cp<major><minor>-<machine>``, e.g. cp313-x86_64 or
cp311-aarch64 (the robot's python and ``uname -m``).  Wheels are cached in
``<cache>/<platform>/``; an unchanged set of requirements downloads nothing
new, and the same wheel file is the same TUF target blob in every release.
A cache that already holds every requirement is used without the index
(``pip download --no-index --find-links``: no resolving against PyPI, which
took 20-60 s); only when it lacks one does pip ask the index (``refresh``
asks it always, for newer versions than the cache holds).
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

from robotfleet.fleet.pull_mode import too_old
from robotfleet.pull.protocol.platforms import parse_platform

# glibc wheel tags pip accepts for a machine, newest first (Debian 12: glibc 2.36, Ubuntu 22.04: 2.35).
_MANYLINUX = (
    "manylinux_2_34_{m}",
    "manylinux_2_28_{m}",
    "manylinux_2_17_{m}",
    "manylinux2014_{m}",
    "manylinux_2_5_{m}",
    "manylinux1_{m}",
)
PIP_TIMEOUT = 1800
# pip evaluates the requirements' markers (``typing-extensions; python_version < '3.11'``) for the
# interpreter it runs in, never for --python-version and --platform: it runs here with the robot's
# values in their place, so a wheelhouse holds what pip on the robot's own Python would install.
_AS_ROBOT = """import runpy, sys
from pip._vendor.packaging import markers
version, machine = sys.argv[1:3]
robot = dict(markers.default_environment(), python_version=version, python_full_version=version + ".0",
             implementation_version=version + ".0", implementation_name="cpython",
             platform_python_implementation="CPython", platform_machine=machine, platform_system="Linux",
             sys_platform="linux", os_name="posix")
markers.default_environment = lambda: dict(robot)
sys.argv = ["pip", *sys.argv[3:]]
runpy.run_module("pip", run_name="__main__", alter_sys=True)
"""


class WheelError(Exception):
    """The wheelhouse cannot be built; the message is one line."""


def pip_command(
    requirements: list[str],
    key: str,
    directory: Path,
    python: str = sys.executable,
    index_url: str | None = None,
    offline: bool = False,
) -> list[str]:
    """The ``pip download`` that fills ``directory`` with ``key``'s wheels
    (``offline``: from the wheels already in ``directory`` only)."""
    version, machine = parse_platform(key)
    command = [
        python,
        "-c",
        _AS_ROBOT,
        version,
        machine,
        "download",
        "--disable-pip-version-check",
        "--no-input",
        "--quiet",
        "--only-binary=:all:",
        "--implementation",
        "cp",
        "--python-version",
        version,
        "--dest",
        str(directory),
    ]
    for tag in _MANYLINUX:
        command += ["--platform", tag.format(m=machine)]
    command += ["--platform", "any"]
    if offline:
        command += ["--no-index", "--find-links", str(directory)]
    elif index_url:
        command += ["--index-url", index_url]
    return command + list(requirements)


def build_wheelhouse(
    requirements: list[str],
    key: str,
    cache_dir,
    python: str = sys.executable,
    index_url: str | None = None,
    refresh: bool = False,
) -> list[Path]:
    """The wheels (sorted paths) that install ``requirements`` on platform
    ``key``, from ``cache_dir``/``key`` when it holds them all, else
    downloaded there from the index (always, with ``refresh``).  WheelError
    (pip's last line) when a requirement has no wheel for that platform."""
    version, _ = parse_platform(key)
    if too_old(version):
        raise WheelError(f"wheels for {key}: a robot's {too_old(version)}")
    directory = Path(cache_dir, key)
    directory.mkdir(parents=True, exist_ok=True)
    if not refresh and any(directory.glob("*.whl")):
        try:
            return _download(requirements, key, directory, python, None, offline=True)
        except WheelError:
            pass  # the cache lacks a requirement: the index has the last word
    return _download(requirements, key, directory, python, index_url)


def _download(requirements, key, directory: Path, python, index_url, offline: bool = False) -> list[Path]:
    log = directory / "pip-download.log"
    log.unlink(missing_ok=True)  # pip appends: only this run's lines say what this set resolved to
    command = pip_command(requirements, key, directory, python, index_url, offline) + ["--log", str(log)]
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=PIP_TIMEOUT, check=False)
    except (OSError, subprocess.TimeoutExpired) as error:
        raise WheelError(f"wheels for {key}: pip download: {error}") from None
    if done.returncode:
        said = [line for line in done.stderr.splitlines() if line.strip() and not line.startswith("WARNING")]
        last = said[-1].strip() if said else "pip download failed"
        missing = re.search(r"No matching distribution found for (\S+)", last)
        if missing:
            version, machine = parse_platform(key)
            last = f"no wheel of {missing[1]} for CPython {version} on {machine} (robots install binary wheels only)"
        raise WheelError(f"wheels for {key}: {last} (pip's log: {log})")
    names = _resolved(log, directory) or sorted(p.name for p in directory.glob("*.whl"))
    return [directory / name for name in sorted(names)]


def _resolved(log: Path, directory: Path) -> list[str]:
    """The wheel files this download resolved to (pip's log names each one
    it saved or found already there), so a cache holding older versions
    does not put them in the release."""
    try:
        text = log.read_text(errors="replace")
    except OSError:
        return []
    names = set(re.findall(r"(?:Saved|File was already downloaded) \S*?([^/\s]+\.whl)", text))
    return sorted(n for n in names if (directory / n).exists())


def requirements_of(pyproject: bytes) -> list[str]:
    """The ``[project] dependencies`` of a pyproject.toml's bytes."""
    try:
        import tomllib
    except ImportError:  # Python 3.10: the same parser, from its own package (pyproject.toml's dependencies)
        import tomli as tomllib
    try:
        return list(tomllib.loads(pyproject.decode())["project"]["dependencies"])
    except (ValueError, KeyError, UnicodeDecodeError) as error:
        raise WheelError(f"pyproject.toml: no [project] dependencies ({error})") from None
