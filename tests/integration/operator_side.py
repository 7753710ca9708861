"""The operator's side as the integration tests drive it: a fleet file of
hosts on 127.0.0.1, connections made through the inventory and pyinfra's
API (as the CLI, status and rollout make them), and a command run in the
checkout with a bare environment."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from pyinfra.api import Config, State
from pyinfra.api.exceptions import ConnectError
from pyinfra.context import ctx_state
from pyinfra_cli.inventory import make_inventory

from robotfleet.fleet import yaml12
from tests.fixtures import ROOT


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
