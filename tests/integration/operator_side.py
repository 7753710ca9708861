"""The operator's side as the integration tests drive it: a fleet file of
hosts on 127.0.0.1, connections made through the inventory and pyinfra's
API (as the CLI, status and rollout make them), a command run in the
checkout with a bare environment, and pyinfra --dry over @fake hosts the
unit harness answers (dry_run, on any Python)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from pyinfra.api import Config, State
from pyinfra.api.exceptions import ConnectError
from pyinfra.context import ctx_state
from pyinfra_cli.inventory import make_inventory

from robotfleet.fleet import yaml12
from tests.fixtures import ROOT, pyinfra_argv


def fleet(tmp_path, hosts: dict, **common) -> Path:
    """A fleet file of ``hosts`` (robots) in tmp_path: its key and known_hosts there, connect
    retries off, a 2 s connect timeout; ``common``: more of all.vars (None: leave the setting out)."""
    path = tmp_path / "fleet.yaml"
    settings = {
        "payload_image": "reg.example.com/p:1",
        "ssh_user": "ops",
        "ssh_key": str(tmp_path / "id_fleet"),
        "ssh_known_hosts_file": str(tmp_path / "known_hosts"),
        "ssh_connect_timeout": 2,
        "ssh_connect_retry_min_delay": 0,
        "ssh_connect_retry_max_delay": 0,
        **common,
    }
    settings = {key: value for key, value in settings.items() if value is not None}
    path.write_text(yaml12.dump({"all": {"vars": settings}, "robots": {"hosts": hosts}}))
    return path


def connect(path: Path, monkeypatch, times: int = 1) -> dict[str, str | None]:
    """Each host's connection error (None: connected), connecting ``times``."""
    monkeypatch.setenv("ROBOT_FLEET", str(path))
    monkeypatch.chdir(ROOT)
    with ctx_state.use(State()):
        inventory = make_inventory("inventories/robots.py", cwd=str(ROOT))
    state = State(inventory=inventory, config=Config())
    outcome = {}
    with ctx_state.use(state):
        for host in inventory:
            for _ in range(times):
                try:
                    host.connect(raise_exceptions=True, show_errors=False)
                    outcome[host.name] = None
                    host.disconnect()
                except ConnectError as error:
                    outcome[host.name] = error.args[0]
    return outcome


def run(path, tmp_path, *argv, timeout=120) -> subprocess.CompletedProcess:
    """``python *argv`` in the checkout as the operator runs it: the fleet file ``path`` in
    $ROBOT_FLEET, an empty known_hosts beside it, nothing else of this environment."""
    (tmp_path / "known_hosts").touch()  # as inventories/known_hosts ships: empty
    env = {
        "PATH": "/usr/bin:/bin",
        "ROBOT_FLEET": str(path),
        "PYINFRA_PROGRESS": "off",
        "HOME": str(tmp_path),
        "ROBOT_ROLLOUT_DIR": str(tmp_path / "rollouts"),
    }
    return subprocess.run([sys.executable, *argv], cwd=ROOT, capture_output=True, text=True, timeout=timeout, env=env)


# pyinfra's CLI over @fake hosts "bad" and "good": fresh Debian 13 hosts as the unit harness answers them
FAKE_HOSTS = (
    "from tests.unit.harness import _Recorder, fresh_host\n"
    '_Recorder({"bad": fresh_host("debian-13"), "good": fresh_host("debian-13")}, {}).__enter__()'
)


def dry_run(tmp_path, python: str = sys.executable) -> str:
    """pyinfra --dry over a robot whose docker_users names a missing account and a good one: its
    output, once it exited 1 having named the reason (tests/integration/test_operator_pythons.py: on
    other Pythons)."""
    host = {"payload_image": "reg.example.com/ros/payload:1.0", "fake_delay": 0, "fake_delay_jitter": 0}
    inventory = tmp_path / "fake.py"
    inventory.write_text(
        f"robots = [('@fake/bad', {{**{host!r}, 'docker_users': ['ops', 'ghost']}}), ('@fake/good', {host!r})]\n"
    )
    env = dict(os.environ, PYTHONPATH=str(ROOT), PYINFRA_PROGRESS="off")
    proc = subprocess.run(
        pyinfra_argv("--dry", str(inventory), "deploy.py", python=python, setup=FAKE_HOSTS),
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    output = proc.stdout + proc.stderr
    assert proc.returncode == 1, output[-3000:]
    planning = output.split("--> Preparing operation", 1)[1].split("--> Detected changes", 1)[0]
    reasons = [line.strip() for line in planning.splitlines() if "ghost" in line]
    assert reasons == [
        "[@fake/bad]  docker_users: ghost does not exist on this host; "
        "create the account first (users are never created by this tool)"
    ]
    return output
