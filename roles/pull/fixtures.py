"""Test fixtures: what a successful run of the pull role leaves on a host."""

import roles.pull as role
import roles.pull.plan as plan
from robotfleet import CHECKOUT
from robotfleet.host.fixtures import file_state
from robotfleet.host.snapshot import FileState
from robotfleet.pull.operator import install
from robotfleet.pull.protocol import agent_files


def converged(play, host: str) -> None:
    data, snap = play.data, play.snapshot
    name = host  # what the steps see as host.name
    for package in plan.PACKAGES:
        snap.packages[package] = "1"
    for path in (agent_files.ETC, agent_files.STATE):
        snap.files[path] = FileState("dir", None, "700", "root", "root")
    snap.files[agent_files.CONFIG] = file_state(agent_files.for_host(data, name, play.roles).to_json(), "600")
    snap.files[agent_files.TRUST_ROOT] = file_state(install.trust_root(CHECKOUT, data.pull_trust_root), "600")
    snap.files[agent_files.KNOWN_HOSTS] = file_state(agent_files.known_hosts(data))
    ca = install.remote_ca(CHECKOUT, data.pull_remote_ca)
    if ca is not None:
        snap.files[agent_files.REMOTE_CA] = file_state(ca)
    snap.files[agent_files.KEY] = file_state("private", "600")
    snap.files[f"{agent_files.KEY}.pub"] = file_state("ssh-ed25519 AAAA robot-pull@" + name, "600")
    snap.files[f"{agent_files.UNIT_DIR}/{agent_files.SERVICE}"] = file_state(agent_files.service_unit())
    snap.files[f"{agent_files.UNIT_DIR}/{agent_files.TIMER}"] = file_state(agent_files.timer_unit(data))
    snap.units[agent_files.TIMER] = ("enabled", "active")
    platform = data.pull_platform
    snap.probes[role.PYTHON_PROBE] = platform.split("-")[0][2:] + "\n"
    venv, _ = install.wheel_set(install.releases_clone(CHECKOUT), platform)
    code, _ = install.code_archive(CHECKOUT)
    snap.probes[role.INSTALLED_PROBE] = f"venv=venvs/{venv}\ncode={code}\n"
