"""roles/udev: stable device names for sensors (one generated rules file)
plus static vendor rules from files/udev/.  Rules are checked before they are
installed; udev is reloaded and triggered only when a rules file changed."""

from __future__ import annotations

import shlex
from pathlib import Path

from pyinfra import host
from pyinfra.api import deploy
from pyinfra.operations.util import any_changed

from roles import operations
from roles.hoststate import Snapshot, SnapshotQuery
from roles.udev import rules

VENDOR_RULES_DIR = Path(__file__).resolve().parents[2] / "files" / "udev"
RULES_DIR = "/etc/udev/rules.d"
VERIFY_PROBE = (
    "if udevadm verify --help >/dev/null 2>&1; then "
    "if udevadm verify --help | grep -q -- --no-style; then echo 'verify-nostyle'; else echo verify; fi; fi"
)


def vendor_rules(data) -> dict[str, str]:
    """Installed path -> content of each static rules file the host asks for."""
    return {
        f"{RULES_DIR}/{name}": (VENDOR_RULES_DIR / name).read_text() for name in data.udev_vendor_rules
    }


def declare_reads(data, query: SnapshotQuery) -> None:
    query.files.add(data.udev_rules_file)
    query.files |= {f"{RULES_DIR}/{name}" for name in data.udev_vendor_rules}
    query.probes["udevadm_verify"] = VERIFY_PROBE


def verify_command(probe: str) -> str | None:
    probe = probe.strip()
    if probe == "verify-nostyle":
        return "udevadm verify --resolve-names=never --no-style {}"
    if probe == "verify":
        return "udevadm verify --resolve-names=never {}"
    return None


def reload_script(subsystems: set[str]) -> str:
    matches = " ".join(f"--subsystem-match={shlex.quote(s)}" for s in sorted(subsystems))
    trigger = f" && udevadm trigger --action=change {matches}" if matches else ""
    return (
        "if udevadm control --ping >/dev/null 2>&1; then "
        f"udevadm control --reload-rules{trigger} && udevadm settle --timeout=30; "
        "else echo 'udevd is not running here; the new rules apply when it starts' >&2; fi"
    )


@deploy("Sensors (udev)")
def sensor_rules(snap: Snapshot):
    data = host.data
    for name in data.udev_vendor_rules:
        if not (VENDOR_RULES_DIR / name).is_file():
            operations.fail(name="Check vendor rules", message=f"udev_vendor_rules: files/udev/{name} does not exist")
            return
    files = dict(vendor_rules(data))
    if data.sensors:
        files[data.udev_rules_file] = rules.render(data.sensors)
    for path, text in files.items():
        problems = rules.lint(text, data.udev_allow_world_writable)
        if problems:
            operations.fail(name="Check udev rules", message=f"udev: {path}: {problems[0]}")
            return

    validate = verify_command(snap.probes.get("udevadm_verify", ""))
    changes = []
    for path, text in host.loop(sorted(files.items())):
        changes.append(
            operations.file(
                name=f"Write udev rules {path}",
                path=path,
                content=text,
                current=snap.files.get(path),
                validate=validate,
            )
        )
    if not data.sensors:
        changes.append(
            operations.absent(name="Remove sensor rules", paths=[data.udev_rules_file], present=snap.files)
        )
    subsystems = set().union(*(rules.subsystems(text) for text in files.values())) if files else set()
    if changes:
        operations.run(
            name="Reload udev rules and trigger the sensors' subsystems",
            script=reload_script(subsystems),
            _if=any_changed(*changes),
        )
