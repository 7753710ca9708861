"""A stock Debian 13 machine with this checkout set up: a plain container of
the lab's host image (python3 3.13 with neither pip nor venv, pip
refusing system installs, sudo), this checkout in /w and `.ci/setup
--python` run in it as root.  One per test session (tests/e2e/conftest.py's
`stock_machine`): the setup's own test (test_stock_machine.py) and the
laptop deploying itself through sudo (test_laptop_sudo.py) share it, so the
test command pays for one setup's pip install, not two."""

from __future__ import annotations

import io
import os
import subprocess
import tarfile
from collections.abc import Iterator
from dataclasses import dataclass
from shlex import quote

from tests.fixtures import ROOT

# The host's trust store: where HTTPS to PyPI goes through an inspecting
# proxy, the machine's own pip trusts it through this bundle.
CA_BUNDLE = "/etc/ssl/certs/ca-certificates.crt"
PASSED_ENV = (
    "http_proxy",
    "https_proxy",
    "no_proxy",
    "HTTP_PROXY",
    "HTTPS_PROXY",
    "NO_PROXY",
    "PIP_INDEX_URL",
    "PIP_EXTRA_INDEX_URL",
)
# The laptop's fleet names it so (inventories/local.py picks the host by it).
HOSTNAME = "devbox"


@dataclass
class StockMachine:
    container: object
    pip_before_setup: tuple[int, str]
    setup: tuple[int, str]

    def sh(self, script: str, user: str | None = None) -> tuple[int, str]:
        """A shell script as root, or as ``user`` in /w."""
        from tests.lab.state import exec_container

        command = script if user is None else f"su {user} -c {quote('cd /w && ' + script)}"
        return exec_container(self.container, command)


def checkout_tar() -> bytes:
    """The files of this checkout that git would see (tracked or not ignored)."""
    names = (
        subprocess.run(
            ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
            cwd=ROOT,
            check=True,
            capture_output=True,
        )
        .stdout.decode()
        .split("\0")
    )
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w") as tar:
        for name in filter(None, names):
            path = ROOT / name
            if path.is_file() or path.is_symlink():
                tar.add(path, arcname=f"w/{name}", recursive=False)
    return buffer.getvalue()


def started(name: str) -> Iterator[StockMachine]:
    """The machine, set up (whatever the setup said: the tests judge it);
    removed after."""
    from tests.lab import engine, hostimage
    from tests.lab.state import exec_container

    dc = engine.client()
    hostimage.ensure_host_image(dc)  # builds the stock rootfs layer if missing
    volumes, environment = {}, {"DEBIAN_FRONTEND": "noninteractive"}
    if os.path.exists(CA_BUNDLE):
        volumes[CA_BUNDLE] = {"bind": "/etc/host-ca.crt", "mode": "ro"}
        environment["PIP_CERT"] = "/etc/host-ca.crt"
    environment.update({k: os.environ[k] for k in PASSED_ENV if k in os.environ})
    for stale in dc.containers.list(all=True, filters={"name": f"^{name}$"}):  # an interrupted run's
        stale.remove(force=True)
    container = dc.containers.create(
        hostimage.base_tag(),
        ["sleep", "1800"],
        name=name,
        hostname=HOSTNAME,
        volumes=volumes,
        environment=environment,
    )
    try:
        container.start()
        container.put_archive("/", checkout_tar())
        pip = exec_container(container, "python3 -m pip --version; pip3 --version")
        yield StockMachine(container, pip, exec_container(container, "cd /w && .ci/setup --python 2>&1"))
    finally:
        container.remove(force=True)
