"""``robotfleet deploy`` (issue 54, item 2): pyinfra's deploy, the same run and
output as ``pyinfra inventories/robots.py deploy.py``, with robotfleet's
INVENTORY (any kind, or -i) and exit codes: 3 when hosts were only out of
reach (pyinfra: 1), 1 when one failed or refused, 2 before any host.  Real
sockets on 127.0.0.1: a closed port, an SSH server that refuses every
command, one whose host key is not known."""

from __future__ import annotations

import re
import subprocess
import sys

import pytest

from tests.fixtures import PYINFRA, ROOT
from tests.integration import sshserver
from tests.integration.operator_side import fleet


@pytest.fixture(autouse=True)
def key(client_key):
    return client_key  # the fleet's ssh_key, there


def run(tmp_path, *argv, cwd=ROOT, fleet_env=None) -> subprocess.CompletedProcess:
    (tmp_path / "known_hosts").touch()
    env = {"PATH": "/usr/bin:/bin", "PYINFRA_PROGRESS": "off", "HOME": str(tmp_path), **(fleet_env or {})}
    return subprocess.run(
        [sys.executable, *argv], cwd=cwd, capture_output=True, text=True, timeout=120, env=env, stdin=subprocess.DEVNULL
    )


def deploy(tmp_path, *argv, **kwargs):
    return run(tmp_path, "-m", "robotfleet", "deploy", *argv, **kwargs)


def test_unreachable_robots_exit_3_with_pyinfras_own_lines(tmp_path):
    closed = sshserver.closed_port()
    path = fleet(
        tmp_path,
        {"robot1": {"address": "127.0.0.1"}, "robot2": {"address": "127.0.0.1"}},
        ssh_port=closed,
        ssh_connect_retries=0,
    )
    ours = deploy(tmp_path, "-i", str(path), "-y")
    theirs = run(
        tmp_path, "-c", PYINFRA, "-y", "inventories/robots.py", "deploy.py", fleet_env={"ROBOT_FLEET": str(path)}
    )
    assert (ours.returncode, theirs.returncode) == (3, 1), ours.stderr
    refused = f"connection refused by 127.0.0.1:{closed} (no SSH server listens on port {closed})"
    assert f"    [robot1] {refused}" in ours.stderr.splitlines()
    assert "--> pyinfra error: No hosts remaining!" in ours.stderr
    # the same run, the same words (the hosts' lines in the order they answered)
    assert (ours.stdout, sorted(ours.stderr.splitlines())) == (theirs.stdout, sorted(theirs.stderr.splitlines()))


def test_a_robot_that_fails_a_step_beside_one_out_of_reach_is_exit_1(tmp_path, client_key):
    server = sshserver.ssh_server(client_key, answer=lambda command: (b"", 1))
    try:
        path = fleet(
            tmp_path,
            {
                "robot1": {"address": "127.0.0.1", "ssh_port": server.port},
                "robot2": {"address": "127.0.0.1", "ssh_port": sshserver.closed_port()},
            },
            ssh_connect_retries=0,
            ssh_strict_host_key_checking="accept-new",
        )
        result = deploy(tmp_path, str(path), "-y", "--limit", "robot1,robot2")
    finally:
        server.close()
    assert result.returncode == 1, result.stderr[-3000:]
    assert server.connections >= 1
    assert "[robot2] connection refused by 127.0.0.1" in result.stderr


def test_an_unknown_host_key_is_a_refusal_exit_1(tmp_path, client_key):
    server = sshserver.ssh_server(client_key)
    try:
        path = fleet(tmp_path, {"robot1": {"address": "127.0.0.1", "ssh_port": server.port}})
        result = deploy(tmp_path, str(path), "--dry")
    finally:
        server.close()
    assert result.returncode == 1, result.stderr[-3000:]
    assert f"[robot1] unknown host key: [127.0.0.1]:{server.port} is not in" in result.stderr


def test_refused_before_any_host_is_exit_2(tmp_path):
    silent = sshserver.Listener()
    try:
        path = fleet(tmp_path, {"robot1": {"address": "127.0.0.1", "ssh_port": silent.port}})
        bad = tmp_path / "bad.yaml"
        bad.write_text(path.read_text().replace("ssh_user", "ssh_usr"))
        cases = {
            ("-i", str(path), "--limit", "bot-z"): "--limit bot-z: no host or group of",
            ("-i", str(tmp_path / "nowhere.yaml")): "nowhere.yaml: no such inventory",
            (str(path), "deplyo.py"): "deploy: deplyo.py: no such file",
            (str(bad),): "ssh_usr: unknown setting (did you mean 'ssh_user'?)",
            (str(path), "-i", str(path)): "the inventory given twice",
        }
        for argv, said in cases.items():
            result = deploy(tmp_path, *argv, "-y")
            assert result.returncode == 2 and said in result.stderr, (argv, result.stderr)
        assert silent.connections == 0
    finally:
        silent.close()


def test_it_runs_from_anywhere_with_the_fleet_as_given(tmp_path):
    """pyinfra itself refuses to run outside the checkout (its config.py and group_data/ would not apply):
    robotfleet deploy runs it there, the fleet named relative to where it was typed."""
    closed = sshserver.closed_port()
    fleet(tmp_path, {"robot1": {"address": "127.0.0.1", "ssh_port": closed}}, ssh_connect_retries=0)
    result = deploy(tmp_path, "fleet.yaml", "--dry", "--diff", cwd=tmp_path)
    assert result.returncode == 3, result.stderr[-3000:]
    assert re.search(rf"\[robot1\] connection refused by 127.0.0.1:{closed}", result.stderr)
    assert not (tmp_path / ".ssh").exists()
