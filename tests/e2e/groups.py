"""The end-to-end modules split into lab groups: each group is one pytest
process on its own lab (prefix ``<ROBOT_LAB_E2E_PREFIX>-<group>``), the
groups run at once (tests/__main__.py), a group's modules one after the
other as in one session.  The host images are the machine's, built once
(tests/lab/machinelock.py).  A module not named here runs in DEFAULT_GROUP.
The modules of WITH_UNIT start containers of their own and no lab: they run
in the unit and integration process, after its tests (it ends minutes
before the lab groups).  The modules of ON_DEMAND are not in the test
command at all: they run when named (`pytest tests/e2e/test_rviz.py`), on a
lab of their own.  Times per module: docs/guides/development.md."""

from __future__ import annotations

from pathlib import Path

E2E_DIR = Path(__file__).resolve().parent
DEFAULT_GROUP = "main"
WITH_UNIT = "with unit and integration"
# Too costly for the test command's 25 minutes: rviz on the laptop builds and pulls a 493 MB image; the
# emulated arm64 robot costs about 900 core-seconds on a fresh machine (its host image under emulation
# about 500, pi1's first run about 415), a third of the command's whole budget on two cores.
ON_DEMAND = ("test_rviz.py", "test_arm64.py")
# Balanced by measured CPU (docs/guides/development.md).
GROUPS: dict[str, tuple[str, ...]] = {
    "pull": ("test_pull.py", "test_pull_https.py", "test_pull_media.py"),
    "hosts": (
        "test_enroll.py",
        "test_hostcerts.py",
        "test_links.py",
        "test_onhost_security.py",
        "test_security.py",
        "test_time.py",
        "test_gpu.py",
        "test_x11.py",
        "test_pull_from_nothing.py",
        "test_ros.py",
        "test_ros_health.py",
    ),
    WITH_UNIT: ("test_stock_machine.py", "test_laptop_sudo.py", "test_ros_graph_probe.py"),
}


def group_of(module: str) -> str:
    return next((group for group, modules in GROUPS.items() if module in modules), DEFAULT_GROUP)


def modules(directory: Path = E2E_DIR) -> list[str]:
    """The modules of the test command (those of ON_DEMAND left out)."""
    return sorted(path.name for path in directory.glob("test_*.py") if path.name not in ON_DEMAND)


def plan(names: list[str]) -> dict[str, list[str]]:
    """{group: its modules} for these module file names; groups without one are left out."""
    planned: dict[str, list[str]] = {}
    for name in names:
        planned.setdefault(group_of(name), []).append(name)
    return {group: planned[group] for group in [DEFAULT_GROUP, *GROUPS] if group in planned}
