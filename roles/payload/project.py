"""The deploy's side of the compose project: what it reads in the host
snapshot, the DDS profile file, the other services' images for push, and
saying what will be taken over (payloadctl does the takeover itself, so it
can undo it)."""

from __future__ import annotations

import json
import shlex

from pyinfra import host, logger

from robotfleet.checkers import one_line
from robotfleet.host import operations
from robotfleet.host.snapshot import Snapshot, SnapshotQuery
import roles.docker.hooks as docker_hooks
from roles.payload.credentials import registry_key
import roles.payload.payloadctl.imageref as imageref
import roles.payload.payloadctl.platforms as platforms
import roles.payload.payloadctl.takeover as takeover_rule
import roles.payload.presets as presets
import roles.payload.push as push
import roles.payload.services as services

FOREIGN_PROBE = "payload_foreign"
# One line per container: id, name, image, compose project, running, restart policy.
_INSPECT = (
    "docker ps -aq --no-trunc 2>/dev/null | xargs -r docker inspect -f "
    + shlex.quote(
        '{{json (printf "%s\\t%s\\t%s\\t%s\\t%v\\t%s" .Id .Name .Config.Image '
        '(index .Config.Labels "com.docker.compose.project") .State.Running .HostConfig.RestartPolicy.Name)}}'
    )
)


def primary_image(data) -> str | None:
    """The image whose registry the login is for (the first service's)."""
    refs = services.images(data)
    return refs[0] if refs else None


def declare_reads(data, query: SnapshotQuery) -> None:
    if data.ros_preset == "ros2" and data.ros_dds_profile:
        query.files |= {presets.dds_profile_host_path(data), f"/etc/{data.payload_name}"}
    if data.payload_autostart:
        query.probes[FOREIGN_PROBE] = _INSPECT
    if data.payload_delivery == "push":
        for index, ref in enumerate(more_images(data)):
            query.probes[f"payload_image_id_{index + 1}"] = image_id_probe(ref)


def platform_refusal(robot: str, arch: str, pins: dict[str, str]) -> str | None:
    """The line refusing a service pinned to a platform this robot (its
    architecture from the snapshot) cannot run, or None."""
    for service, pinned in sorted(pins.items()):
        if arch and not platforms.matches(arch, platforms.parse(pinned)):
            return "payload: " + platforms.pinned_refusal(robot, arch, service, pinned)
    return None


def more_images(data) -> list[str]:
    """Images beyond the first (whose push the single-image code does)."""
    return services.images(data)[1:]


def image_id_probe(ref: str) -> str:
    return f"docker image inspect -f '{{{{.Id}}}}' {shlex.quote(ref)}"


def push_target(data, snap: Snapshot, credentials) -> dict:
    """Who a push is for: the robot, its architecture (from the snapshot),
    and how to read the image's registry for its own variant."""
    return {"robot": host.name, "arch": snap.arch, "insecure": docker_hooks.insecure_registries(data),
            "credentials": credentials}


def push_more_images(data, snap: Snapshot, auths: dict | None = None) -> None:
    """payload_delivery push for a project of several images: each one the
    robot lacks is sent (layers the robot has are left out, as for the
    first), read from its registry with that registry's own credentials
    (``auths``: registry -> Credentials or None)."""
    if data.payload_delivery != "push":
        return
    layers = push.parse_layer_sets(snap.probes.get("docker_layers", ""))
    for index, ref in enumerate(more_images(data)):
        credentials = (auths or {}).get(registry_key(imageref.parse(ref).registry))
        push.push_image(
            name=f"Send the payload image {ref} over SSH",
            image=ref,
            remote_id=snap.probes.get(f"payload_image_id_{index + 1}", "").strip(),
            remote_layers=layers,
            log_dir=data.payload_dir,
            **push_target(data, snap, credentials),
        )


def takeover_of(data) -> dict:
    """What payloadctl may take over (the spec's "takeover"): the primary
    image's repository, and what payload_replaces names."""
    return {"primary": imageref.repository(primary_image(data) or ""),
            **takeover_rule.parse_replaces(data.payload_replaces)}


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
        container = {"id": cid[:12], "name": name.lstrip("/"), "image": image, "project": label or None,
                     "running": running == "true", "restart": policy or "no",
                     "repositories": [imageref.repository(image)]}
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
    found = foreign(snap.probes.get(FOREIGN_PROBE, ""), data.payload_name, takeover_of(data), recorded)
    if found:
        # Names and images come from the robot: one line, nothing that moves the cursor.
        logger.warning(f"[{host.name}] {one_line(takeover_line(found))}")
    return found


def install_files(data, snap: Snapshot) -> None:
    """The ROS 2 DDS profile, read-only for the containers."""
    if data.ros_preset != "ros2" or not data.ros_dds_profile:
        return
    path = presets.dds_profile_host_path(data)
    operations.directory(name=f"/etc/{data.payload_name}", path=f"/etc/{data.payload_name}",
                         current=snap.files.get(f"/etc/{data.payload_name}"))
    operations.file(name=f"DDS profile {data.ros_dds_profile}", path=path,
                    content=presets.dds_profile_text(data), current=snap.files.get(path), mode="0644")
