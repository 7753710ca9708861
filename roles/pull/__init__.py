"""roles/pull: the agent that lets a robot converge itself (pull mode).

Where ``pull_enabled`` is true, a push deploy installs the agent: git and
python3-venv, a venv made from the operator's wheels for the robot's
python and architecture, the deploy tree the agent runs, its configuration
and the release repository's root.json (root's only), the robot's own SSH
key for the fleet remote (made on the robot; it never leaves it), and
robot-pull.service run by robot-pull.timer.  When the agent itself runs the
deploy (a release, robotfleet/pull/robot/agent.py), the venv and the tree are
the release's, which the agent put in place: the role leaves them alone.
docs/guides/pull.md says how to use it, docs/explanations/pull.md how it all fits; roles/pull/README.md
what the role does.
"""

from __future__ import annotations

from pyinfra import host
from pyinfra.api import deploy, operation
from pyinfra.operations.util import any_changed

import roles.pull.plan as plan
from robotfleet import CHECKOUT
from robotfleet.fleet import pull_mode
from robotfleet.host import apt, operations
from robotfleet.host.snapshot import SnapshotQuery
from robotfleet.host.stream import FileStdin
from robotfleet.pull.operator import install
from robotfleet.pull.protocol import agent_files
from robotfleet.role import Play, Role

INSTALLED_PROBE = "pull_installed"
PYTHON_PROBE = "pull_python"
# Set in a host's data by the agent when it runs the deploy itself.
AGENT_RUN = agent_files.AGENT_RUN
FILES = (
    agent_files.CONFIG,
    agent_files.TRUST_ROOT,
    agent_files.KNOWN_HOSTS,
    agent_files.REMOTE_CA,
    agent_files.KEY,
    f"{agent_files.KEY}.pub",
    f"{agent_files.UNIT_DIR}/{agent_files.SERVICE}",
    f"{agent_files.UNIT_DIR}/{agent_files.TIMER}",
)


runs_on = pull_mode.pulls


def declare_reads(data, query: SnapshotQuery) -> None:
    query.packages |= set(plan.PACKAGES)
    query.files |= {agent_files.ETC, agent_files.STATE, *FILES}
    query.units.add(agent_files.TIMER)
    query.probes[INSTALLED_PROBE] = install.PROBE
    query.probes[PYTHON_PROBE] = plan.PYTHON_PROBE


def robot_name(data) -> str:
    """The robot's name in the fleet (its report's, its git user's): the
    host's, or the agent's when it runs the deploy as @local."""
    return (data.get(AGENT_RUN) or {}).get("robot") or host.name


@deploy("Pull agent")
def pull_agent(play: Play):
    data, snap = play.data, play.snapshot
    name = robot_name(data)
    agent_run = bool(data.get(AGENT_RUN))
    if not agent_run:  # the agent's own run: the robot already trusts, and follows root changes itself
        try:
            root = install.trust_root(CHECKOUT, data.pull_trust_root)
        except install.InstallError as error:
            operations.fail(name="Read the release repository's root.json", message=str(error))
            return
    try:
        ca = install.remote_ca(CHECKOUT, data.pull_remote_ca)
    except install.InstallError as error:
        operations.fail(name="Read the fleet remote's CA", message=str(error))
        return
    apt.apt_install(
        name="Install git and python3-venv for the pull agent", packages=list(plan.PACKAGES), installed=snap.packages
    )
    for path in (agent_files.ETC, agent_files.STATE):
        operations.directory(name=f"Pull agent directory {path}", path=path, current=snap.files.get(path), mode="0700")
    operations.file(
        name="Write the pull agent's configuration",
        path=agent_files.CONFIG,
        content=agent_files.for_host(data, name, play.roles).to_json(),
        current=snap.files.get(agent_files.CONFIG),
        mode="0600",
    )
    if not agent_run:
        operations.file(
            name="Write the release repository's root.json (the agent's first trust)",
            path=agent_files.TRUST_ROOT,
            content=root,
            current=snap.files.get(agent_files.TRUST_ROOT),
            mode="0600",
        )
    operations.file(
        name="Write the fleet remote's host keys",
        path=agent_files.KNOWN_HOSTS,
        content=agent_files.known_hosts(data),
        current=snap.files.get(agent_files.KNOWN_HOSTS),
    )
    if ca is not None:
        operations.file(
            name="Write the CA the https fleet remote's certificate is checked against",
            path=agent_files.REMOTE_CA,
            content=ca,
            current=snap.files.get(agent_files.REMOTE_CA),
        )
    elif snap.files.get(agent_files.REMOTE_CA) is not None:
        operations.absent(
            name="Remove the fleet remote's CA (pull_remote_ca is not set)",
            paths=[agent_files.REMOTE_CA],
            present=snap.files,
        )
    if snap.files.get(agent_files.KEY) is None or snap.files.get(f"{agent_files.KEY}.pub") is None:
        operations.run(
            name="Make the robot's own key for the fleet remote (it never leaves the robot)",
            script=plan.keygen_script(name),
        )
    if not agent_run:
        _install_venv_and_code(data, snap)
    units = [
        operations.file(
            name=f"Write {agent_files.SERVICE}",
            path=f"{agent_files.UNIT_DIR}/{agent_files.SERVICE}",
            content=agent_files.service_unit(),
            current=snap.files.get(f"{agent_files.UNIT_DIR}/{agent_files.SERVICE}"),
        ),
        operations.file(
            name=f"Write {agent_files.TIMER}",
            path=f"{agent_files.UNIT_DIR}/{agent_files.TIMER}",
            content=agent_files.timer_unit(data),
            current=snap.files.get(f"{agent_files.UNIT_DIR}/{agent_files.TIMER}"),
        ),
    ]
    operations.run(name="systemd daemon-reload", script="systemctl daemon-reload", _if=any_changed(*units))
    operations.run(
        name=f"Restart {agent_files.TIMER} with its new schedule",
        script=f"systemctl restart {agent_files.TIMER}",
        _if=any_changed(*units[1:]),
    )
    operations.service(
        name=f"{agent_files.TIMER} enabled and running",
        unit=agent_files.TIMER,
        enabled_now=snap.unit_enabled(agent_files.TIMER),
        active_now=snap.unit_active(agent_files.TIMER),
    )


def refuses(data, snap) -> str | None:
    """A robot whose python3 (or, without one, its release's) is too old for
    the agent: refused before any role changes anything on it."""
    if data.get(AGENT_RUN):
        return None  # the agent runs there already
    platform = plan.platform(snap.probes.get(PYTHON_PROBE, ""), snap.os_release, snap.arch)
    old = pull_mode.too_old(platform[2:].split("-")[0]) if platform else None
    return f"this robot's {old}" if old else None


def _install_venv_and_code(data, snap) -> None:
    platform = plan.platform(snap.probes.get(PYTHON_PROBE, ""), snap.os_release, snap.arch)
    if platform != data.pull_platform:
        operations.fail(
            name="Check pull_platform against the robot",
            message=f"pull_platform: {data.pull_platform}, but this robot runs "
            f"{platform or 'a python or machine without wheels'}; its releases carry the "
            f"wheels of pull_platform" + (f" (set pull_platform: {platform})" if platform else ""),
        )
        return
    installed = install.read_probe(snap.probes.get(INSTALLED_PROBE, ""))
    try:
        venv, files = install.wheel_set(install.releases_clone(CHECKOUT), platform)
        code, archive = install.code_archive(CHECKOUT)
    except install.InstallError as error:
        operations.fail(name="Find what the pull agent runs", message=f"pull: {error}")
        return
    send(
        name=f"Make the pull agent's venv from {len(files)} wheels ({platform})",
        wanted=venv,
        present=installed["venv"],
        script=install.venv_script(venv),
        archive=install.wheels_archive(files),
    )
    send(
        name=f"Install the deploy tree the pull agent runs ({code[:12]})",
        wanted=code,
        present=installed["code"],
        script=install.code_script(code),
        archive=archive,
    )


@operation()
def send(wanted: str, present: str, script: str, archive: str):
    """Run ``script`` with the local file ``archive`` on its stdin unless the
    robot already has ``wanted``."""
    if wanted == present:
        host.noop(f"{wanted} is in place")
        return
    yield operations.shell(script, stdin=FileStdin(archive))


ROLE = Role(
    name="pull",
    doc="Pull mode: the agent that fetches, verifies and applies signed releases on the robot itself.",
    runs_on=runs_on,
    reads=declare_reads,
    steps=pull_agent,
    refuses=refuses,
)
