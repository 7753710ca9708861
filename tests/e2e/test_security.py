"""End to end: a key that does not match its pin fails that host and leaves
nothing behind; registry credentials reach robots without being printed."""

from __future__ import annotations

import json

import pytest

pytestmark = pytest.mark.e2e


def test_apt_key_fingerprint_mismatch_fails_the_host_and_keeps_the_trusted_key(lab, first_run):
    before = lab.ok("robot1", "sha256sum /etc/apt/keyrings/docker.asc")
    run = lab.provision(
        "--limit", "robot1", "--data", "docker_apt_key_fingerprint=" + "DEAD" * 10, label="(wrong key pin)"
    )
    assert run.returncode != 0  # the only host of the run failed: pyinfra says "No hosts remaining!"
    assert f"does not match docker_apt_key_fingerprint {'DEAD' * 10}; key not installed" in run.output
    assert lab.ok("robot1", "sha256sum /etc/apt/keyrings/docker.asc") == before
    assert lab.ok("robot1", "ls -A /etc/apt/keyrings").split() == ["docker.asc"]  # no temp file left


def test_registry_credentials_are_used_but_never_printed(lab, first_run):
    secret = "s3cret-registry-token-4711"
    env = {"PAYLOAD_REGISTRY_USERNAME": "robot-puller", "PAYLOAD_REGISTRY_PASSWORD": secret}
    lab.ok("robot2", f"docker logout {lab.state['registry']}")
    run = lab.provision("-vv", "--limit", "robot2", env=env, label="(registry login, -vv)")
    assert run.returncode == 0, run.output[-3000:]
    assert "Payload | Log in to the payload registry" in run.changes("robot2")
    assert secret not in run.output
    config = lab.ok("robot2", "cat /root/.docker/config.json")
    assert lab.state["registry"] in json.loads(config)["auths"]
    assert lab.ok("robot2", "stat -c %a /root/.docker/config.json").strip() == "600"
    again = lab.provision("--limit", "robot2", env=env, label="(registry login, again)")
    assert again.changed_hosts == set()
