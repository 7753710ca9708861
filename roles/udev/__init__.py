"""roles/udev: stable device names for sensors (one generated rules file)
plus static vendor rules from files/udev/.  Rules are checked before they are
installed; udev is reloaded and triggered only when a rules file changed."""

from __future__ import annotations

import shlex
from pathlib import Path

from pyinfra import host
from pyinfra.api import deploy
from pyinfra.operations.util import any_changed

import roles.payload.hooks as payload_hooks
from robotfleet.host import operations
from robotfleet.host.snapshot import SnapshotQuery
from robotfleet.role import Play, Role
from roles.udev import passthrough, rules, settings

VENDOR_RULES_DIR = Path(__file__).resolve().parents[2] / "files" / "udev"
RULES_DIR = "/etc/udev/rules.d"
VERIFY_PROBE = (
    "if h=$(udevadm verify --help 2>/dev/null); then "
    "case $h in *--no-style*) echo 'verify-nostyle' ;; *) echo verify ;; esac; fi"
)


def vendor_rules(data) -> dict[str, str]:
    """Installed path -> content of each static rules file the host asks for."""
    return {f"{RULES_DIR}/{name}": (VENDOR_RULES_DIR / name).read_text() for name in data.udev_vendor_rules}


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
    """Reload the rules, then trigger the rules' subsystems one by one.  The
    rules are in place by now, so a failed reload or trigger (some devices
    refuse it; so does a read-only /sys) is a warning naming the subsystem
    and device, never a failed host: the devices get their names when
    re-plugged or at the next boot."""
    later = "the new rules apply when the devices are re-plugged or at the next boot"
    lines = [
        "if ! udevadm control --ping >/dev/null 2>&1; then",
        f"  echo 'warning: udev: udevd is not running here; {later}' >&2; exit 0",
        "fi",
        "if ! out=$(udevadm control --reload-rules 2>&1); then",
        f'  echo "warning: udev: reloading the rules failed ($(echo "$out" | tail -n 1)); {later}" >&2; exit 0',
        "fi",
    ]
    for subsystem in sorted(subsystems):
        s = shlex.quote(subsystem)
        lines += [
            f"if ! out=$(udevadm trigger --action=change --subsystem-match={s} 2>&1); then",
            f'  echo "warning: udev: udevadm trigger failed for subsystem {subsystem}: '
            f'$(echo "$out" | grep . | tail -n 1 | cut -c1-200); {later}" >&2',
            "fi",
        ]
    lines.append("udevadm settle --timeout=30 || echo 'warning: udev: udevadm settle timed out after 30 s' >&2")
    lines.append("exit 0")
    return "\n".join(lines)


@operations.operation(is_idempotent=False)
def reload_rules(subsystems: set[str]):
    """Reload udev and trigger the subsystems (gated by the caller with ``_if``)."""
    yield operations.shell_with_warnings(reload_script(subsystems))


@deploy("Sensors (udev)")
def sensor_rules(play: Play):
    data, snap = play.data, play.snapshot
    for name in data.udev_vendor_rules:
        if not (VENDOR_RULES_DIR / name).is_file():
            operations.fail(name="Check vendor rules", message=f"udev_vendor_rules: files/udev/{name} does not exist")
            return
    files = dict(vendor_rules(data))
    if data.udev_sensors:
        files[data.udev_rules_file] = rules.render(data.udev_sensors)
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
    if not data.udev_sensors:
        changes.append(operations.absent(name="Remove sensor rules", paths=[data.udev_rules_file], present=snap.files))
    subsystems = set().union(*(rules.subsystems(text) for text in files.values())) if files else set()
    if changes:
        reload_rules(
            name="Reload udev rules and trigger the sensors' subsystems",
            subsystems=subsystems,
            _if=any_changed(*changes),
        )


ROLE = Role(
    name="udev",
    doc="udev rules that give sensors stable names (two identical cameras become front/back); "
    "the payload gets the devices.",
    settings=settings.SETTINGS,
    runs_on=lambda data: bool(data.udev_sensors or data.udev_vendor_rules),
    reads=declare_reads,
    steps=sensor_rules,
    renamed=settings.RENAMED,
    rules=lambda data, refused: settings.rules(data, refused) + passthrough.problems(data, refused),
    adds={payload_hooks.SERVICES: passthrough.devices_for},
)
