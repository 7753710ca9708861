"""The payload's part of the operator commands: its status columns (from
payloadctl status on the robot) and what a rollout waits for (every image of
the robot's compose project running healthy)."""

from __future__ import annotations

import datetime
import json
import shlex

import roles.payload.digests as digests
from robotfleet.checkers import one_line
from robotfleet.role import Metric, RolloutPart, StatusPart
from roles.payload.installed_files import HELPER

# HEALTH of a container whose image declares no health check (Docker reports none).
NO_CHECK = "no check"


def status_command(data) -> str:
    q = shlex.quote
    return (
        f"[ -x {HELPER} ] && /usr/bin/python3 {HELPER} status --dir {q(data.payload_dir)}"
        f" --name {q(data.payload_name)} --lock-file {q(data.payload_update_lock_path)}"
    )


def cells(output: str) -> dict:
    """Status cells from payloadctl's JSON report (pure); {} before the
    first deploy."""
    report = next((json.loads(line) for line in output.splitlines() if line.strip().startswith("{")), {})
    current = report.get("current") or {}
    previous = report.get("previous") or {}
    containers = report.get("containers") or []
    named = {i.get("pinned"): digests.shown(ref, i.get("pinned")) for ref, i in (current.get("images") or {}).items()}
    images = list(named.values())
    return {
        "release": current.get("id"),
        "image": images[0] if len(images) == 1 else (", ".join(images) or None),
        "state": ", ".join(c["status"] for c in containers) or None,
        "health": ", ".join(c.get("health") or NO_CHECK for c in containers) or None,
        "restarts": sum(c.get("restarts", 0) for c in containers),
        "previous": previous.get("id"),
        "deployed": current.get("rolled_back_to") or current.get("activated") or current.get("created"),
        "release_state": current.get("state"),
        "lock": report.get("update_lock"),
        "rolled_back_from": current.get("rolled_back_from"),
        **per_service(report.get("services") or {}, named),
        "image_refs": sorted(current.get("images") or {}),
        "result": last_result(report.get("result")),
        "releases": [r for r in report.get("releases") or [] if isinstance(r, dict) and r.get("id")] or None,
        # ros_health: "ok" or what the graph lacks, looked at now (None: the release declares no graph)
        "graph": report.get("graph") if isinstance(report.get("graph"), str) else None,
    }


def last_result(result) -> dict | None:
    """payloadctl's structured result of the robot's last apply or rollback
    (format 1), as status --json shows it and a rollout reads it."""
    if not isinstance(result, dict) or result.get("payloadctl") != 1 or not isinstance(result.get("ok"), bool):
        return None
    return result


def result(row: dict, deployment: str) -> tuple[bool, str] | None:
    """The payload's result of the deploy named ``deployment`` on this host
    (None: its last result is another deploy's, or it has none)."""
    found = row.get("result") or {}
    if not deployment or found.get("deployment") != deployment:
        return None
    return found["ok"], one_line(str(found.get("message") or found.get("reason") or found.get("outcome")))


def per_service(states: dict, named: dict | None = None) -> dict:
    """A project of several services: each one's image (with its tag, from
    ``named``: the container's reference by digest -> the release's name for
    it), state and health (the table's columns name the service; --json
    has them whole)."""
    if len(states) < 2:
        return {"services": states or None} if states else {}
    ordered = sorted(states.items())
    named = named or {}
    return {
        "services": states,
        "image": ", ".join(f"{name}={named.get(s.get('image'), s.get('image'))}" for name, s in ordered),
        "state": ", ".join(f"{name}:{s.get('state')}" for name, s in ordered),
        "health": ", ".join(f"{name}:{s.get('health') or NO_CHECK}" for name, s in ordered),
    }


def target(data) -> list[str]:
    """What a rollout waits for: every image of the host's compose project,
    as it runs (by a release's digest where it is given pins)."""
    return sorted(digests.images(data))


def missing(row: dict, wanted: list[str]) -> str | None:
    """None when ``row`` shows every image of ``wanted`` in the current
    release, healthy (or staged, on a host without autostart); else why not."""
    if not row.get("reachable"):
        return row.get("error") or "unreachable"
    if row.get("error"):
        return row["error"]
    images = row.get("image_refs") or []
    absent = [ref for ref in wanted if not any(digests.runs(running, ref) for running in images)]
    back = row.get("rolled_back_from") or {}
    if absent and back.get("reason"):
        return f"release failed ({back['reason']}); rolled back to {row.get('release')}"
    if absent:
        return f"runs {', '.join(images or ['nothing'])}, not {', '.join(absent)}"
    state = row.get("release_state")
    if state == "staged":
        return None
    if state == "active" and healthy(row):
        graph = row.get("graph")
        return None if graph in (None, "ok") else f"ROS graph: {graph}"
    return f"release {row.get('release')} is {state}, containers {row.get('state')}/{row.get('health')}"


def healthy(row: dict) -> bool:
    """Every container of the release running, healthy (or without a health check)."""
    health = (row.get("health") or "").split(", ")
    states = (row.get("state") or "").split(", ")
    return all(s.rsplit(":", 1)[-1] == "running" for s in states) and all(
        h.rsplit(":", 1)[-1] in ("healthy", NO_CHECK, "none") for h in health
    )  # "none": an older robot's report


def metrics(row: dict) -> list[Metric]:
    """The payload's gauges for robotfleet status --metrics."""
    found = []
    if row.get("release"):
        found.append(
            Metric(
                "payload_release_info",
                "The payload release the host runs, its state and the previous one.",
                1,
                (
                    ("release", row["release"]),
                    ("state", row.get("release_state") or ""),
                    ("previous", row.get("previous") or ""),
                ),
            )
        )
    if row.get("state"):
        found.append(
            Metric(
                "payload_healthy",
                "1 every payload container runs healthy (or has no health check), 0 not.",
                1 if healthy(row) else 0,
            )
        )
        found.append(Metric("payload_restarts", "Restarts of the payload's containers.", row.get("restarts") or 0))
    if row.get("graph"):
        found.append(
            Metric(
                "payload_ros_graph_ok",
                "1 the ROS graph shows what ros_health declares, 0 not.",
                int(row["graph"] == "ok"),
            )
        )
    deployed = row.get("deployed")
    try:
        when = datetime.datetime.fromisoformat(str(deployed).replace("Z", "+00:00")) if deployed else None
    except ValueError:
        when = None
    if when is not None:
        found.append(
            Metric(
                "payload_last_change_timestamp_seconds",
                "When the payload's current release was activated or rolled back to (Unix time).",
                when.timestamp(),
            )
        )
    return found


def history(row: dict) -> list[tuple[str, str]]:
    """The host's releases as its row tells them, newest first (pure): each
    release kept on it (current, previous or its state; when; why it failed),
    or from an older payloadctl the current one, the one rolled back from and
    the previous one; then the last run's result when it did not succeed."""
    found = [_kept(kept, row) for kept in row.get("releases") or []] or _pointers(row)
    result = row.get("result") or {}
    if result and not result.get("ok"):
        found.append(("last run", f"{result.get('outcome')}: {result.get('reason') or result.get('message')}"))
    return found


def _kept(kept: dict, row: dict) -> tuple[str, str]:
    what = {row.get("release"): "current", row.get("previous"): "previous"}.get(kept["id"], kept.get("state"))
    when = kept.get("activated") or kept.get("created")
    why = f": {kept['reason']}" if kept.get("reason") else ""
    return str(what), f"{kept['id']} ({kept.get('state')}{f', {when}' if when else ''}){why}"


def _pointers(row: dict) -> list[tuple[str, str]]:
    found = []
    if row.get("release"):
        since = f" since {row['deployed']}" if row.get("deployed") else ""
        found.append(("current", f"{row['release']} ({row.get('release_state') or 'state unknown'}{since})"))
    back = row.get("rolled_back_from") or {}
    if back.get("id"):
        when = f" at {back['time']}" if back.get("time") else ""
        found.append(("rolled back from", f"{back['id']}{when}: {back.get('reason') or 'no reason given'}"))
    if row.get("previous"):
        found.append(("previous", str(row["previous"])))
    return found


def watch(data) -> list[str]:
    """What changes when the payload's status may have: its directory (the
    current and previous links and last-result.json are renamed into it)
    and its unit's invocation (each start of it, at boot or by hand)."""
    return [data.payload_dir, f"/run/systemd/units/invocation:{data.payload_name}.service"]


STATUS = StatusPart(
    command=status_command,
    cells=cells,
    columns=(
        ("release", "RELEASE"),
        ("image", "IMAGE"),
        ("state", "STATE"),
        ("health", "HEALTH"),
        ("graph", "GRAPH"),
        ("previous", "PREVIOUS"),
        ("deployed", "LAST DEPLOY"),
        ("lock", "LOCK"),
    ),
    # The default table fits 100 characters; a graph that falls short is also the row's drift (counted "drifted").
    wide=("image", "graph", "previous", "deployed", "lock"),
    order=20,
    metrics=metrics,
    watch=watch,
    history=history,
)
ROLLOUT = RolloutPart(target=target, missing=missing, result=result)
