"""The payload role's steps: the helper and the unit in place, the image
where the robot can use it, and a release when what runs is not what the
fleet file says."""

from __future__ import annotations

import shlex

from pyinfra import host
from pyinfra.api import deploy
from pyinfra.operations.util import any_changed

import roles.docker.hooks as docker_hooks
import roles.payload.compose as compose
import roles.payload.containers as containers
import roles.payload.credentials as credentials
import roles.payload.dds_profile as dds_profile
import roles.payload.hooks as hooks
import roles.payload.image_transfer as image_transfer
import roles.payload.installed_files as installed_files
import roles.payload.login as login
import roles.payload.payloadctl.imageref as imageref
import roles.payload.payloadctl.platforms as platforms
import roles.payload.release as release
import roles.payload.ros_health as ros_health
import roles.payload.ros_logs as ros_logs
import roles.payload.secret_files as secret_files
import roles.payload.services as services
import roles.payload.takeover_plan as takeover_plan
import roles.payload.transferred_images as transferred_images
from robotfleet.host import apt, operations
from robotfleet.host.snapshot import SnapshotQuery
from robotfleet.role import Play


def declare_reads(data, query: SnapshotQuery) -> None:
    query.files |= {installed_files.HELPER, installed_files.unit_path(data), data.payload_dir}
    query.units.add(f"{data.payload_name}.service")
    query.commands |= {"python3", "systemd-run"}
    query.probes["payload_record"] = f"cat {shlex.quote(data.payload_dir)}/current/record.json"
    query.probes[containers.PROBE] = containers.probe(data.payload_name, foreign=data.payload_autostart)
    query.probes["payload_lock"] = release.lock_probe(data.payload_dir)
    query.probes["registry_auth"] = login.registry_probe(imageref.parse(services.primary_image(data)).registry)
    if data.payload_delivery == "pull":
        for registry in other_registries_with_credentials(data):
            query.probes[login_probe(registry)] = login.registry_probe(registry)
    dds_profile.declare_reads(data, query)
    ros_logs.declare_reads(data, query)
    secret_files.declare_reads(data, query)
    transferred_images.declare_reads(data, query)
    if data.payload_delivery == "push":
        query.probes["payload_image_id"] = (
            f"docker image inspect -f '{{{{.Id}}}}' {shlex.quote(services.primary_image(data))}"
        )
        query.probes["docker_layers"] = image_transfer.LAYERS_PROBE


def other_registries_with_credentials(data) -> list[str]:
    """The registries besides the primary's that the payload's images come
    from and payload_registry_auths gives credentials for."""
    configured = credentials.entries(data)
    return [r for r in credentials.registries(data)[1:] if r in configured]


def login_probe(registry: str) -> str:
    return f"registry_auth {registry}"


def read_credentials(data) -> dict:
    """registry -> its own Credentials (or None) for every registry the
    payload's images come from; CredentialError if a configured one is unreadable."""
    return {registry: credentials.lookup(data, registry) for registry in credentials.registries(data)}


def platform_refusal(robot: str, arch: str, pins: dict[str, str]) -> str | None:
    """The line refusing a service pinned to a platform this robot (its
    architecture from the snapshot) cannot run, or None."""
    for service, pinned in sorted(pins.items()):
        if arch and not platforms.matches(arch, platforms.parse(pinned)):
            return "payload: " + platforms.pinned_refusal(robot, arch, service, pinned)
    return None


def unit_devices(additions: list[dict]) -> list[str]:
    """Device paths the unit waits for at boot: those the other roles give
    the services (the sensors), not those a service declares itself."""
    found = []
    for added in additions:
        for service in added.values():
            for device in service.get("devices") or []:
                path = device.split(":", 1)[0]
                if path not in found:
                    found.append(path)
    return found


@deploy("Payload")
def deploy_payload(play: Play):
    data, snap = play.data, play.snapshot
    refused = platform_refusal(host.name, snap.arch, services.platforms(data))
    if refused:
        operations.fail(name="Check the payload's platform against the robot's", message=refused)
        return
    try:
        auths = read_credentials(data)
    except credentials.CredentialError as error:
        operations.fail(name="Read the registry credentials", message=f"payload: {error}")
        return
    address = data.get("ssh_hostname") or host.name
    additions = play.added(hooks.SERVICES, services.declared(data))
    doc = compose.project(data, address, additions)

    if not snap.commands.get("python3"):
        apt.apt_install(name="Install python3 for payloadctl", packages=["python3"], installed=snap.packages)
    operations.directory(
        name=f"Payload releases directory {data.payload_dir}",
        path=data.payload_dir,
        current=snap.files.get(data.payload_dir),
    )
    operations.file(
        name="Install the release helper payloadctl",
        path=installed_files.HELPER,
        content=installed_files.helper_bytes(),
        current=snap.files.get(installed_files.HELPER),
        mode="0755",
    )

    unit = installed_files.unit_path(data)
    unit_content = installed_files.unit_text(data, unit_devices(additions))
    unit_changes = data.payload_autostart and not operations.file_matches(
        snap.files.get(unit), unit_content.encode(), "0644", "root", "root"
    )
    if data.payload_autostart:
        unit_op = operations.file(
            name=f"Write the autostart unit {data.payload_name}.service",
            path=unit,
            content=unit_content,
            current=snap.files.get(unit),
        )
        operations.run(name="systemd daemon-reload", script="systemctl daemon-reload", _if=unit_op.did_change)
        operations.service(
            name=f"Enable {data.payload_name}.service at boot",
            unit=f"{data.payload_name}.service",
            enabled_now=snap.unit_enabled(f"{data.payload_name}.service"),
            active_now=snap.unit_active(f"{data.payload_name}.service"),
            running=False,  # starting it is the release step's job (health-gated)
        )
    else:
        removed = operations.absent(name="Remove the payload autostart unit", paths=[unit], present=snap.files)
        operations.run(
            name="Disable the payload autostart unit",
            script=f"systemctl disable {shlex.quote(data.payload_name)}.service 2>/dev/null; systemctl daemon-reload",
            _if=removed.did_change,
        )

    primary = imageref.parse(services.primary_image(data)).registry
    if data.payload_delivery == "pull":
        # Each registry's own credentials, to that registry only.
        for registry, own in auths.items():
            if own is None:
                continue
            first = registry == credentials.registry_key(primary)
            login.registry_login(
                name="Log in to the payload registry" if first else f"Log in to the registry {registry}",
                registry=primary if first else registry,
                username=own.username,
                password=own.password,
                stored=snap.probes.get("registry_auth" if first else login_probe(registry), ""),
            )
    if data.payload_delivery == "push":
        image_transfer.push_image(
            name="Send the payload image over SSH",
            image=services.primary_image(data),
            remote_id=snap.probes.get("payload_image_id", "").strip(),
            remote_layers=image_transfer.parse_layer_sets(snap.probes.get("docker_layers", "")),
            log_dir=data.payload_dir,
            **transferred_images.push_target(data, snap, auths.get(credentials.registry_key(primary))),
        )
        transferred_images.push_more_images(data, snap, auths)

    dds_profile.install_files(data, snap)
    ros_logs.install(data, snap)
    secrets_changed = secret_files.place(data, snap)
    if secrets_changed is None:
        return
    release.say_who_holds_the_lock(snap.probes.get("payload_lock", ""))
    # said in the output, done by payloadctl
    taken_over = takeover_plan.takeover(data, snap, release.current_record(snap))
    needed = release.release_needed(
        release.current_record(snap),
        compose.spec_hash(doc, data.payload_autostart),
        data.payload_autostart,
        # Both: the containers really run (the oneshot unit stays "active"
        # without them) and the unit did not fail (it starts them at boot).
        release.containers_running(containers.part(snap.probes.get(containers.PROBE, ""), "c"))
        and snap.unit_active(f"{data.payload_name}.service"),
    )
    # A changed secret file: the containers are made anew, with it (compose binds it when it creates them).
    needed = needed or unit_changes or bool(taken_over) or secrets_changed
    the_release = {"data": data, "document": doc, "checks": [*play.added(hooks.CHECKS), ros_health.graph_check(data)]}
    release.release(
        name="Release the payload (pull, switch, health check, roll back on failure)",
        needed=needed,
        restart=unit_changes or bool(taken_over) or secrets_changed,
        **the_release,
    )
    restarts = play.announced(docker_hooks.RESTARTED)
    if restarts and not needed:
        # A daemon.json Docker accepts can still lose the payload (a new
        # data-root, userns-remap): the same release, checked and made again
        # if its containers are gone, under the health gate.
        release.release(
            name="Check the payload after Docker restarted (released again if it does not run)",
            needed=True,
            restart=False,
            _if=any_changed(*restarts),
            **the_release,
        )
