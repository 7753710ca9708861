"""End to end: the setup's Python part on a stock Debian 13 machine.

The lab's host image (an mmdebstrap rootfs) is such a machine: python3 (3.13) with neither
pip nor venv, and pip refusing system installs (PEP 668).  A plain container
of it gets this checkout and runs `.ci/setup --python` as root (the session's
`stock_machine`, tests/e2e/stock_machine.py, which test_laptop_sudo.py
shares), then a smoke of the unit layer from the virtual environment the
setup made, and the setup again, which changes nothing.
"""

from __future__ import annotations

import time

import pytest

from tests.e2e.conftest import phase

pytestmark = pytest.mark.e2e

SMOKE = ["tests/unit/test_validation.py", "tests/unit/test_rendering.py"]


def test_setup_and_unit_smoke_on_a_stock_debian_13(stock_machine):
    code, out = stock_machine.pip_before_setup
    assert code != 0, f"the stock rootfs unexpectedly has pip: {out}"
    code, out = stock_machine.setup
    assert code == 0, out[-4000:]
    started = time.monotonic()
    smoke = ".venv/bin/python -m pytest -q -p no:cacheprovider -m 'not e2e' " + " ".join(SMOKE)
    code, text = stock_machine.sh(f"cd /w && {smoke} 2>&1")
    assert code == 0 and " passed" in text, text[-4000:]
    # A second setup finds everything in place and changes nothing.
    code, out = stock_machine.sh("cd /w && .ci/setup --python 2>&1")
    assert code == 0 and "-->" not in out, out
    phase("stock Debian 13: unit smoke and a second .ci/setup --python", started)
