"""The build of this checkout (`pip install -e .`): setuptools' own, after
refusing in one line a Python that pyinfra 3 does not run on.  pip checks
the project's requires-python only once every dependency resolved, so on
Ubuntu 20.04's Python 3.8 it ended on "No matching distribution found for
tuf<8,>=7" instead.  pip imports it on the Python being installed for, so it
is written for any Python 3 (pyproject.toml: build-backend)."""

import sys

# pyproject.toml's requires-python (tests/unit/test_readme_operator_path.py holds them equal).
MINIMUM = (3, 10)

if sys.version_info[:2] < MINIMUM:
    raise SystemExit(
        "robot-fleet-provisioner needs Python %d.%d or later (pyinfra 3), and this is Python %d.%d: "
        "make the venv with a newer Python (docs/guides/install.md, Ubuntu 20.04)" % (MINIMUM + sys.version_info[:2])
    )

from setuptools.build_meta import *  # noqa: E402, F403  (every hook is setuptools')
