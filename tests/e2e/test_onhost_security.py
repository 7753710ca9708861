"""End to end, issue 8 on a robot: the keyring holds exactly the pinned key,
a symlinked daemon.json converges, compose values reach the container
verbatim, and a changed registry password is applied without being shown."""

from __future__ import annotations

import base64
import subprocess

import pytest

pytestmark = pytest.mark.e2e

KEYRING = "/etc/apt/keyrings/docker.asc"


def _put(lab, host: str, path: str, content: bytes) -> None:
    lab.ok(host, f"echo {base64.b64encode(content).decode()} | base64 -d > {path}")


def _intruder_key(tmp_path) -> bytes:
    home = tmp_path / "gnupg"
    home.mkdir(mode=0o700)
    gpg = ["gpg", "--batch", "--homedir", str(home)]
    subprocess.run(
        gpg + ["--passphrase", "", "--quick-gen-key", "intruder@example", "ed25519", "sign", "never"],
        capture_output=True,
        check=True,
    )
    return subprocess.run(gpg + ["--armor", "--export"], capture_output=True, check=True).stdout


def test_compose_values_reach_the_container_verbatim(lab, first_run):
    """inventories/lab.yaml gives the robots `pay$day` and `${X:?}`: compose
    would have made the first `pay` and refused to start on the second."""
    env = lab.payload("robot1")["Config"]["Env"]
    assert "ROBOT_MOTTO=pay$day" in env and "ROBOT_TEMPLATE=${X:?}" in env


def test_a_poisoned_keyring_is_repaired_and_a_two_key_file_refused(lab, first_run, tmp_path):
    good = lab.ok("robot1", f"sha256sum {KEYRING}").split()[0]
    _put(lab, "robot1", "/root/intruder.asc", _intruder_key(tmp_path))
    poison = f"cat /root/intruder.asc >> {KEYRING}"

    # Docker's key + another on the robot, the mirror serves the right one: repaired.
    lab.ok("robot1", poison)
    run = lab.provision("--limit", "robot1", label="(poisoned keyring)")
    assert run.returncode == 0, run.output[-3000:]
    assert any("apt key" in name for name in run.changes("robot1")), run.changes("robot1")
    assert lab.ok("robot1", f"sha256sum {KEYRING}").split()[0] == good

    # The key URL serves Docker's key + another: refused, and the poisoned keyring is not kept.
    lab.ok("robot1", f"mkdir -p /root/keysrv && cat {KEYRING} /root/intruder.asc > /root/keysrv/gpg")
    lab.ok(
        "robot1",
        "systemd-run --unit=e2e-keysrv --collect python3 -m http.server 8765 --bind 127.0.0.1 "
        "--directory /root/keysrv && for i in $(seq 50); do "
        "curl -fso /dev/null http://127.0.0.1:8765/gpg && exit 0; sleep 0.2; done; exit 1",
    )
    try:
        lab.ok("robot1", poison)
        bad = lab.provision(
            "--limit", "robot1", "--data", "docker_apt_key_url=http://127.0.0.1:8765/gpg", label="(two-key file)"
        )
        assert bad.returncode != 0
        assert "holds 2 keys" in bad.output and "key not installed" in bad.output
        assert lab.ok("robot1", "ls -A /etc/apt/keyrings").split() == []
    finally:
        lab.sh("robot1", "systemctl stop e2e-keysrv")
    again = lab.provision("--limit", "robot1", label="(keyring restored)")
    assert again.returncode == 0, again.output[-3000:]
    assert lab.ok("robot1", f"sha256sum {KEYRING}").split()[0] == good


def test_a_symlinked_daemon_json_is_replaced_once(lab, first_run):
    invocation = "systemctl show -p InvocationID --value docker.service"
    lab.ok(
        "robot2",
        "cp /etc/docker/daemon.json /root/daemon.json.real && ln -sfn /root/daemon.json.real /etc/docker/daemon.json",
    )
    started = lab.ok("robot2", invocation).strip()
    run = lab.provision("--limit", "robot2", label="(daemon.json symlinked)")
    assert run.returncode == 0, run.output[-3000:]
    assert [c for c in run.changes("robot2") if "daemon.json" in c] == [
        "Docker | Write /etc/docker/daemon.json and restart Docker "
        "(the previous file comes back if Docker does not start)"
    ]
    assert lab.ok("robot2", "readlink -f /root/daemon.json.real") and lab.ok(
        "robot2", "cat /root/daemon.json.real"
    )  # the link's target is left alone
    assert lab.ok("robot2", "stat -c %F /etc/docker/daemon.json").strip() == "regular file"
    restarted = lab.ok("robot2", invocation).strip()
    assert restarted != started
    again = lab.provision("--limit", "robot2", label="(daemon.json, again)")
    assert again.changed_hosts == set()
    assert lab.ok("robot2", invocation).strip() == restarted


def test_a_changed_registry_password_logs_in_again_and_is_never_shown(lab, first_run):
    user = {"PAYLOAD_REGISTRY_USERNAME": "robot-puller"}
    first, second = "first-s3cret-4711", "second-s3cret-4712"
    login = "Payload | Log in to the payload registry"
    record = "cat /root/.docker/robotprov-login-*"

    run = lab.provision(
        "-vv", "--limit", "robot2", env={**user, "PAYLOAD_REGISTRY_PASSWORD": first}, label="(registry login)"
    )
    assert run.returncode == 0, run.output[-3000:]
    assert login in run.changes("robot2") and first not in run.output
    stored = lab.ok("robot2", record)
    assert first not in stored and "robot-puller" not in stored
    assert lab.ok("robot2", "stat -c %a /root/.docker/robotprov-login-*").strip() == "600"

    same = lab.provision("--limit", "robot2", env={**user, "PAYLOAD_REGISTRY_PASSWORD": first}, label="(same password)")
    assert same.returncode == 0 and same.changed_hosts == set()

    changed = lab.provision(
        "-vv", "--limit", "robot2", env={**user, "PAYLOAD_REGISTRY_PASSWORD": second}, label="(changed password)"
    )
    assert changed.returncode == 0, changed.output[-3000:]
    assert changed.changes("robot2") == [login]
    assert second not in changed.output and first not in changed.output
    assert lab.ok("robot2", record) != stored
    auth = lab.ok("robot2", "cat /root/.docker/config.json")
    assert base64.b64encode(f"robot-puller:{second}".encode()).decode() in auth
