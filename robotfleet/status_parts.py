"""A host's status as its roles read it: one shell command made of the
engine's part and each role's status part (deploy.py's roles), its output
cut into the parts again, and a row of cells from them.  Pure; ``robotfleet
status`` runs it over SSH, a pull robot's converge run on itself."""

from __future__ import annotations

from robotfleet import reasons

MARK = "@@@robot-fleet-status "
# The engine's own section (no role is called so: a role's name is an identifier).
HOST_SECTION = "engine:host"
HOST_COMMAND = "dpkg --print-architecture"
FIRST = [("host", "HOST"), ("reachable", "REACHABLE"), ("arch", "ARCH")]
LAST = [("rollout", "ROLLOUT")]
ENGINE_WIDE = ("arch",)


def reporting(roles) -> list:
    """The roles with a status part, in the table's order."""
    return sorted((r for r in roles if r.status), key=lambda r: r.status.order)


def columns(roles, wide: bool = True) -> list[tuple[str, str]]:
    """The table's columns: every one (``wide``, as ``status -o wide``), or
    those that fit 100 characters, without the ones the engine and the
    roles mark wide."""
    hidden = set() if wide else {*ENGINE_WIDE, *(key for role in reporting(roles) for key in role.status.wide)}
    every = FIRST + [column for role in reporting(roles) for column in role.status.columns] + LAST
    return [column for column in every if column[0] not in hidden]


def status_command(roles, data) -> str:
    """The host's one status command: the engine's part, then each role's,
    each after a marker line."""
    parts = [(HOST_SECTION, HOST_COMMAND)] + [(role.name, role.status.command(data)) for role in reporting(roles)]
    return "; ".join(f"echo '{MARK}{name}'; ( {command} ) 2>/dev/null" for name, command in parts) + "; true"


def sections(stdout: str) -> dict[str, str]:
    """The status command's output, by role name (pure)."""
    found: dict[str, list[str]] = {}
    current = None
    for line in stdout.splitlines():
        if line.startswith(MARK):
            current = line[len(MARK) :].strip()
            found[current] = []
        elif current is not None:
            found[current].append(line)
    return {name: "\n".join(lines) for name, lines in found.items()}


def row(name: str, roles, parts: dict[str, str] | None, error: str | None = None) -> dict:
    """A table row from the roles' sections of the output (pure); None:
    the host did not answer."""
    if parts is None:
        return {"host": name, "reachable": False, "error": error}
    cells = {"host": name, "reachable": True, "arch": parts.get(HOST_SECTION, "").strip() or None}
    for role in reporting(roles):
        try:
            cells.update(role.status.cells(parts.get(role.name, "")))
        except ValueError:
            cells["error"] = f"unreadable {role.name} status"
    return cells


def state_of(row: dict) -> str:
    """A row's state for the summary (pure): unreachable (the network's, or
    a pull robot with no fresh report or out of reach of its remote), failed
    (answered with an error, a host key or login refused, a pull release
    refused, failed or rolled back), drifted (answered, not in its declared
    state: status's drift), else healthy."""
    error = row.get("error")
    if error and (row.get("reachable") or not reasons.unreachable(error)):
        return "failed"
    if not row.get("reachable"):
        return "unreachable"
    return "drifted" if row.get("drift") else "healthy"
