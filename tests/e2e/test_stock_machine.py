"""End to end: the setup's Python part on a stock Debian 13 machine.

The lab's debootstrap rootfs is such a machine: python3 (3.13) with neither
pip nor venv, and pip refusing system installs (PEP 668).  A plain container
of it gets this checkout, runs `.ci/setup --python` as root, then a smoke of
the unit layer from the virtual environment the setup made.
"""

from __future__ import annotations

import io
import os
import subprocess
import tarfile
import time

import pytest

from tests.e2e.conftest import ROOT, phase
from tests.lab.state import exec_container

pytestmark = pytest.mark.e2e

SMOKE = ["tests/unit/test_validation.py", "tests/unit/test_rendering.py"]
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


def test_setup_and_unit_smoke_on_a_stock_debian_13(tmp_path):
    from tests.lab import engine, hostimage

    dc = engine.client()
    hostimage.ensure_host_image(dc)  # builds the stock rootfs layer if missing
    image = hostimage.base_tag()
    volumes = {}
    environment = {"DEBIAN_FRONTEND": "noninteractive"}
    if os.path.exists(CA_BUNDLE):
        volumes[CA_BUNDLE] = {"bind": "/etc/host-ca.crt", "mode": "ro"}
        environment["PIP_CERT"] = "/etc/host-ca.crt"
    environment.update({k: os.environ[k] for k in PASSED_ENV if k in os.environ})

    started = time.monotonic()
    container = dc.containers.create(image, ["sleep", "900"], volumes=volumes, environment=environment)
    try:
        container.start()
        container.put_archive("/", checkout_tar())
        code, out = exec_container(container, "python3 -m pip --version; pip3 --version")
        assert code != 0, f"the stock rootfs unexpectedly has pip: {out}"
        code, out = exec_container(container, "cd /w && .ci/setup --python 2>&1")
        assert code == 0, out[-4000:]
        smoke = ".venv/bin/python -m pytest -q -p no:cacheprovider -m 'not e2e' " + " ".join(SMOKE)
        code, text = exec_container(container, f"cd /w && {smoke} 2>&1")
        assert code == 0 and " passed" in text, text[-4000:]
        # A second setup finds everything in place and changes nothing.
        code, out = exec_container(container, "cd /w && .ci/setup --python 2>&1")
        assert code == 0 and "-->" not in out, out
    finally:
        container.remove(force=True)
        phase("stock Debian 13: .ci/setup --python + unit smoke", started)
