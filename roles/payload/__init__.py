"""roles/payload: the ROS payload as releases run by a systemd unit.

The deploy computes the compose document from host data; when it differs from
the robot's current release (or the unit changed, or the payload is down), it
hands the spec to payloadctl on the robot, which pulls first, switches,
waits for health and rolls back on failure.  Nothing changes otherwise.
"""

from __future__ import annotations

import datetime
import getpass
import hashlib
import hmac
import json
import os
import secrets
import shlex
import socket
from pathlib import Path

import jinja2
from pyinfra import host
from pyinfra.api import deploy

from roles import imageref, operations, x11
from roles.hoststate import Snapshot, SnapshotQuery
from roles.gpu import plan as gpu_plan
from roles.payload import compose, project, push
from roles.udev import rules

HERE = Path(__file__).resolve().parent
HELPER = "/usr/local/lib/robot-payload/payloadctl"


def unit_path(data) -> str:
    return f"/etc/systemd/system/{data.payload_name}.service"


def helper_text() -> str:
    return (HERE / "payloadctl.py").read_text()


def unit_text(data, devices: list[str]) -> str:
    template = jinja2.Template((HERE / "payload.service.j2").read_text(), keep_trailing_newline=True)
    return template.render(
        name=data.payload_name,
        dir=data.payload_dir,
        helper=HELPER,
        devices=devices,
        device_wait=data.payload_device_wait,
    )


def desired_compose(data, address: str) -> dict:
    gui = x11.compose_settings(data) if data.display else None
    return compose.project(data, address, gui)  # issue 13: every service (the shorthand's document unchanged)


def spec(data, doc: dict) -> dict:
    return {
        "name": data.payload_name,
        "dir": data.payload_dir,
        "compose": doc,
        "spec_hash": compose.spec_hash(doc, data.payload_autostart),
        "autostart": data.payload_autostart,
        "delivery": data.payload_delivery,
        "health_timeout": data.payload_health_timeout,
        "pull_timeout": data.payload_pull_timeout,
        "apply_lock_timeout": data.payload_apply_lock_timeout,
        "stable_seconds": data.payload_stable_seconds,
        "keep_releases": data.payload_keep_releases,
        "lock_file": data.payload_lock_file,
        "force": data.payload_force,
        "deployed_by": f"{getpass.getuser()}@{socket.gethostname()} (pyinfra)",
        "gpu_check": gpu_plan.check_command(data),  # payloadctl: run in each container once healthy
    }


def current_record(snap: Snapshot) -> dict:
    try:
        record = json.loads(snap.probes.get("payload_record") or "{}")
    except ValueError:
        return {}
    return record if isinstance(record, dict) else {}


def containers_probe(name: str) -> str:
    return (
        f"docker ps -a --filter label=com.docker.compose.project={shlex.quote(name)}"
        " --format '{{.State}}\t{{.Status}}'"
    )


def containers_running(probe_output: str) -> bool:
    """From `docker ps`: the payload's containers exist, all run, none is
    unhealthy (a oneshot unit stays "active" when they are gone)."""
    lines = [line.split("\t", 1) for line in probe_output.splitlines() if line.strip()]
    return bool(lines) and all(
        state == "running" and "(unhealthy)" not in (rest[0] if rest else "") for state, *rest in lines
    )


RELEASED = ("active", "staged")


def release_needed(record: dict, wanted_hash: str, autostart: bool, running: bool) -> bool:
    """A release is converged only when it is what was asked, it passed its
    health gate (a failed or interrupted one is tried again) and, where it
    should run, its containers really run."""
    if record.get("spec_hash") != wanted_hash or record.get("state") not in RELEASED:
        return True
    return autostart and not running


def new_run_id() -> str:
    """Names this run's spec, result and transient unit on the robot."""
    return datetime.datetime.now(datetime.timezone.utc).strftime("%Y%m%dT%H%M%S") + "-" + secrets.token_hex(4)


DOCKER_CONFIG_DIR = "/root/.docker"
DOCKER_HUB_NAMES = ("docker.io", "index.docker.io", "registry-1.docker.io")
LOGIN_ITERATIONS = 100_000


def registry_config_key(registry: str) -> str:
    """The key `docker login` stores a registry's credentials under."""
    return "https://index.docker.io/v1/" if registry in DOCKER_HUB_NAMES else registry


def login_record_path(registry: str) -> str:
    name = hashlib.sha256(registry_config_key(registry).encode()).hexdigest()[:16]
    return f"{DOCKER_CONFIG_DIR}/robotprov-login-{name}"


def credentials_record(registry: str, username: str, password: str, salt: str | None = None) -> str:
    """What the robot keeps (0600) to know which credentials it is logged in
    with: a salted PBKDF2 of (registry, username, password), never the password."""
    salt = salt or os.urandom(16).hex()
    secret = json.dumps([registry_config_key(registry), username, password]).encode()
    digest = hashlib.pbkdf2_hmac("sha256", secret, bytes.fromhex(salt), LOGIN_ITERATIONS).hex()
    return f"pbkdf2-sha256:{LOGIN_ITERATIONS}:{salt}:{digest}"


def credentials_match(stored: str, registry: str, username: str, password: str) -> bool:
    parts = stored.strip().split(":")
    if len(parts) != 4 or parts[0] != "pbkdf2-sha256" or parts[1] != str(LOGIN_ITERATIONS):
        return False
    try:
        wanted = credentials_record(registry, username, password, salt=parts[2])
    except ValueError:  # not a hex salt
        return False
    return hmac.compare_digest(wanted, stored.strip())


def registry_probe(registry: str) -> str:
    """The stored credentials record, if Docker still holds a login there."""
    q = shlex.quote
    return (
        f"grep -qF {q(json.dumps(registry_config_key(registry)))} {DOCKER_CONFIG_DIR}/config.json"
        f" && cat {q(login_record_path(registry))}"
    )


def declare_reads(data, query: SnapshotQuery) -> None:
    query.files |= {HELPER, unit_path(data), data.payload_dir}
    query.units.add(f"{data.payload_name}.service")
    query.commands |= {"python3", "systemd-run"}
    query.probes["payload_record"] = f"cat {shlex.quote(data.payload_dir)}/current/record.json"
    query.probes["payload_containers"] = containers_probe(data.payload_name)
    query.probes["registry_auth"] = registry_probe(imageref.parse(project.primary_image(data)).registry)
    project.declare_reads(data, query)  # issue 13
    if data.payload_delivery == "push":
        query.probes["payload_image_id"] = (
            f"docker image inspect -f '{{{{.Id}}}}' {shlex.quote(project.primary_image(data))}"
        )
        query.probes["docker_layers"] = push.LAYERS_PROBE


def run_path(data, run_id: str) -> str:
    """This run's own directory on the robot (spec and result): two deploys
    at once never share a file."""
    return f"{data.payload_dir}/runs/{run_id}"


def on_robot(data, action: str, arguments: str, run_id: str, prelude: str = "", unit: str | None = None) -> str:
    """Run ``payloadctl <action> <arguments>`` as a transient systemd unit (so
    it goes on if SSH drops), then print the result it recorded for this run
    and exit with it; no result for this run fails the host."""
    q = shlex.quote
    helper = f"/usr/bin/python3 {HELPER}"
    command = f"{helper} {action} {arguments} --run-id {q(run_id)} >/dev/null 2>&1 || true"
    unit_name = f"{data.payload_name}-{unit or action}-{run_id}"
    return (
        f"{prelude}"
        "if command -v systemd-run >/dev/null 2>&1 && [ -d /run/systemd/system ]; then\n"
        f"  systemd-run --quiet --wait --collect --unit={q(unit_name)} {command}\n"
        "else\n"
        f"  {command}\n"
        "fi\n"
        f"exec {helper} result --dir {q(data.payload_dir)} --name {q(data.payload_name)} --run-id {q(run_id)}\n"
    )


def staging_prelude(data, run_id: str, what: str, stdin_to: str | None = None) -> str:
    q = shlex.quote
    directory = run_path(data, run_id)
    fail = f"{{ echo {q(f'payload: cannot write the {what} on this robot (disk full?)')} >&2; exit 1; }}"
    lines = ["umask 077", f"mkdir -p {q(directory)} || {fail}"]
    if stdin_to:
        lines.append(f"cat > {q(directory + '/' + stdin_to)} || {fail}")
    return "\n".join(lines) + "\n"


def apply_script(data, restart: bool, run_id: str) -> str:
    spec_path = shlex.quote(run_path(data, run_id) + "/spec.json")
    prelude = staging_prelude(data, run_id, "spec of this update", "spec.json")
    return on_robot(data, "apply", spec_path + (" --restart" if restart else ""), run_id, prelude, unit="update")


@operations.operation()
def release(data, document: dict, needed: bool, restart: bool):
    """Apply the release on the robot when it is not what runs there."""
    if not needed:
        host.noop("payload release is current")
        return
    run_id = new_run_id()
    payload = json.dumps({**spec(data, document), "run_id": run_id}, sort_keys=True)
    yield operations.shell(apply_script(data, restart, run_id), stdin=payload.splitlines())


@operations.operation()
def registry_login(registry: str, username: str, password: str, stored: str):
    """Log in unless the robot's record says it is logged in with exactly
    these credentials (a changed password is applied).  The record and the
    password go over stdin, so neither is on a command line."""
    if credentials_match(stored, registry, username, password):
        host.noop(f"logged in to {registry}")
        return
    q = shlex.quote
    script = (
        "set -e\n"
        "read -r record\n"
        f"docker login {q(registry)} --username {q(username)} --password-stdin >/dev/null\n"
        "umask 077\n"
        f"path={q(login_record_path(registry))}\n"
        'tmp=$(mktemp "$(dirname "$path")/.robotprov.XXXXXX")\n'
        "trap 'rm -f \"$tmp\"' EXIT\n"
        'printf "%s\\n" "$record" > "$tmp"\n'
        'sync "$tmp"\n'
        'mv -fT "$tmp" "$path"\n'
        "trap - EXIT\n"
    )
    yield operations.shell(script, stdin=[credentials_record(registry, username, password), password])


@deploy("Payload")
def deploy_payload(snap: Snapshot):
    data = host.data
    address = data.get("ssh_hostname") or host.name
    doc = desired_compose(data, address)
    devices = rules.devices(data.sensors)

    if not snap.commands.get("python3"):
        operations.apt_install(name="Install python3 for payloadctl", packages=["python3"], installed=snap.packages)
    operations.directory(name=f"Payload releases directory {data.payload_dir}", path=data.payload_dir, current=snap.files.get(data.payload_dir))
    operations.file(
        name="Install the release helper payloadctl",
        path=HELPER,
        content=helper_text(),
        current=snap.files.get(HELPER),
        mode="0755",
    )

    unit = unit_path(data)
    unit_content = unit_text(data, devices)
    unit_changes = data.payload_autostart and not operations.file_matches(
        snap.files.get(unit), unit_content.encode(), "0644", "root", "root"
    )
    if data.payload_autostart:
        unit_op = operations.file(name=f"Write the autostart unit {data.payload_name}.service", path=unit, content=unit_content, current=snap.files.get(unit))
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

    username = os.environ.get(data.payload_registry_username_env)
    password = os.environ.get(data.payload_registry_password_env)
    if data.payload_delivery == "pull" and username and password:
        registry_login(
            name="Log in to the payload registry",
            registry=imageref.parse(project.primary_image(data)).registry,
            username=username,
            password=password,
            stored=snap.probes.get("registry_auth", ""),
        )
    if data.payload_delivery == "push":
        push.push_image(
            name="Send the payload image over SSH",
            image=project.primary_image(data),
            remote_id=snap.probes.get("payload_image_id", "").strip(),
            remote_layers=push.parse_layer_sets(snap.probes.get("docker_layers", "")),
            log_dir=data.payload_dir,
        )
        project.push_more_images(data, snap)  # issue 13: the other services' images

    project.install_files(data, snap)  # issue 13: the DDS profile
    taken_over = project.takeover(data, snap)  # issue 13: said in the output, done by payloadctl
    needed = release_needed(
        current_record(snap),
        compose.spec_hash(doc, data.payload_autostart),
        data.payload_autostart,
        # Both: the containers really run (the oneshot unit stays "active"
        # without them) and the unit did not fail (it starts them at boot).
        containers_running(snap.probes.get("payload_containers", ""))
        and snap.unit_active(f"{data.payload_name}.service"),
    )
    release(
        name="Release the payload (pull, switch, health check, roll back on failure)",
        data=data,
        document=doc,
        needed=needed or unit_changes or bool(taken_over),
        restart=unit_changes or bool(taken_over),
    )


def rollback_script(data, run_id: str) -> str:
    q = shlex.quote
    by = f"{getpass.getuser()}@{socket.gethostname()} (pyinfra rollback)"
    arguments = (
        f"--dir {q(data.payload_dir)} --name {q(data.payload_name)} --lock-file {q(data.payload_lock_file)}"
        f" --health-timeout {int(data.payload_health_timeout)} --stable-seconds {int(data.payload_stable_seconds)}"
        f" --apply-lock-timeout {int(data.payload_apply_lock_timeout)} --by {q(by)}"
        + (" --force" if data.payload_force else "")
    )
    prelude = (
        f"[ -x {HELPER} ] || {{ echo 'payload: no releases on this host (never deployed)' >&2; exit 1; }}\n"
        + staging_prelude(data, run_id, "result directory of this rollback")
    )
    return on_robot(data, "rollback", arguments, run_id, prelude)


@deploy("Rollback")
def rollback_release(data):
    operations.run(name="Switch the payload back to the previous release", script=rollback_script(data, new_run_id()))
