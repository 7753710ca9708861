"""What the release will take over, said in the run output before it is
done: the containers that run the payload another way (the containers
probe the payload role declares, roles/payload/containers.py), judged by
payloadctl's own rule (payloadctl/takeover.py), which does the takeover
itself so it can undo it."""

from __future__ import annotations

import json

from pyinfra import host, logger

import roles.payload.containers as containers
import roles.payload.payloadctl.imageref as imageref
import roles.payload.payloadctl.takeover as takeover_rule
import roles.payload.services as services
from robotfleet.checkers import one_line
from robotfleet.host.snapshot import Snapshot


def takeover_of(data) -> dict:
    """What payloadctl may take over (the spec's "takeover"): the primary
    image's repository, and what payload_replaces names."""
    return {
        "primary": imageref.repository(services.primary_image(data) or ""),
        **takeover_rule.parse_replaces(data.payload_replaces),
    }


def foreign(probe_output: str, project: str, takeover: dict, recorded=()) -> list[dict]:
    """The containers the release will take over, from the probe (pure; the
    rule is payloadctl's own, takeover.reason; ``recorded``: the compose
    projects the robot's current release says its payload used)."""
    found = []
    for line in probe_output.splitlines():
        try:
            cid, name, image, label, running, policy = json.loads(line).split("\t")
        except (ValueError, AttributeError):
            continue
        # No such label: Docker's printf renders the missing value as "%!s(<nil>)".
        label = "" if label.startswith("%!") or label == "<no value>" else label
        container = {
            "id": cid[:12],
            "name": name.lstrip("/"),
            "image": image,
            "project": label or None,
            "running": running == "true",
            "restart": policy or "no",
            "repositories": [imageref.repository(image)],
        }
        why = takeover_rule.reason(container, project, takeover, recorded)
        if why:
            found.append(dict(container, why=why))
    return found


def takeover_line(found: list[dict]) -> str:
    parts = []
    for c in found:
        what = f"compose project {c['project']}, " if c["project"] else ""
        state = "running" if c["running"] else "stopped"
        parts.append(f"{c['name']} ({what}{c['image']}, {state}, restart {c['restart']}: {c['why']})")
    return "payload: taking over what runs the payload another way (stopped, restart policy no): " + "; ".join(parts)


def takeover(data, snap: Snapshot, current_record: dict | None = None) -> list[dict]:
    """What the release will stop, said in the run output (``current_record``:
    the robot's current release record, from the snapshot)."""
    if not data.payload_autostart:
        return []
    recorded = takeover_rule.recorded_projects(current_record, data.payload_name)
    found = foreign(
        containers.part(snap.probes.get(containers.PROBE, ""), "f"), data.payload_name, takeover_of(data), recorded
    )
    if found:
        # Names and images come from the robot: one line, nothing that moves the cursor.
        logger.warning(f"[{host.name}] {one_line(takeover_line(found))}")
    return found
