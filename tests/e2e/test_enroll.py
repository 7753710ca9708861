"""End to end, first contact (issue 18): from an empty known_hosts to a first
deploy through `robotfleet enroll`, on a simulated robot over SSH;
then the robot's host key changes (its sshd gets new keys) and the change is
refused, by enroll and by the deploy, with the file left as it was.

    ROBOT_LAB_E2E_PREFIX=op .venv/bin/python -m pytest tests/e2e/test_enroll.py -m e2e -q
"""

from __future__ import annotations

import base64
import hashlib
import json
import os
import subprocess
import sys
import time

import pytest

from tests.e2e.conftest import ROOT, one_robot_lab, phase
from tests.fixtures import PYINFRA

pytestmark = pytest.mark.e2e


def fingerprint(line: str) -> str:
    """SHA256:... of a known_hosts line's key, computed here (not by the engine)."""
    blob = base64.b64decode(line.split()[2])
    return "SHA256:" + base64.b64encode(hashlib.sha256(blob).digest()).decode().rstrip("=")


@pytest.fixture(scope="module")
def lab():
    """One robot nobody enrolled, whose host key the test changes (a lab of its own)."""
    yield from one_robot_lab("enroll")


@pytest.fixture
def first_contact(lab, tmp_path):
    known_hosts = tmp_path / "known_hosts"
    known_hosts.write_text("")  # as inventories/known_hosts ships
    env = dict(os.environ, ROBOT_LAB_PREFIX=lab.prefix, ROBOT_LAB_KNOWN_HOSTS=str(known_hosts), PYINFRA_PROGRESS="off")

    def run(label: str, *argv: str, timeout: int = 1500) -> subprocess.CompletedProcess:
        started = time.monotonic()
        proc = subprocess.run(
            [sys.executable, *argv], cwd=ROOT, env=env, capture_output=True, text=True, timeout=timeout
        )
        phase(f"{label} (exit {proc.returncode})", started)
        return proc

    run.known_hosts = known_hosts
    return run


def test_from_an_empty_known_hosts_to_a_first_deploy_then_a_changed_key_is_refused(lab, first_contact, tmp_path):
    port = next(h["port"] for h in lab.state["hosts"] if h["name"] == "robot1")
    entry = f"[127.0.0.1]:{port}"
    deploy = ("-c", PYINFRA, "-y", "inventories/lab.py", "deploy.py", "--limit", "robot1")

    # 1. Strict checking against an empty file: one line naming the file and the fix, no retries.
    refused = first_contact("deploy before enrolling", *deploy, timeout=300)
    assert refused.returncode != 0
    robot_lines = [line.strip() for line in refused.stderr.splitlines() if line.strip().startswith("[robot1]")]
    assert robot_lines == [
        f"[robot1] unknown host key: {entry} is not in {first_contact.known_hosts} "
        "(ssh_strict_host_key_checking: yes); check and enroll it: "
        "robotfleet enroll inventories/lab.py --limit robot1"
    ], refused.stderr
    assert "Traceback" not in refused.stderr

    # 2. Enroll from the fingerprints the lab recorded when it made the host (as a vendor would).
    recorded = [line for line in open(lab.state["known_hosts"]).read().splitlines() if line.startswith(entry + " ")]
    assert recorded
    fingerprints = tmp_path / "fingerprints.txt"
    fingerprints.write_text("".join(f"robot1 {fingerprint(line)}\n" for line in recorded))
    enrolled = first_contact(
        "enroll robot1",
        "-m",
        "robotfleet",
        "enroll",
        "inventories/lab.py",
        "--limit",
        "robot1",
        "--fingerprints",
        str(fingerprints),
        timeout=120,
    )
    assert enrolled.returncode == 0, enrolled.stderr
    assert f"matches {fingerprints}; enrolled" in enrolled.stderr
    lines = first_contact.known_hosts.read_text().splitlines()
    assert len(lines) == 1 and lines[0].startswith(entry + " ") and lines[0] in recorded

    # 3. The first deploy, then status, with strict checking.
    first = first_contact("first deploy of robot1", *deploy, "--json")
    assert first.returncode == 0, first.stderr[-6000:]
    status = first_contact(
        "status robot1", "-m", "robotfleet", "status", "inventories/lab.py", "--limit", "robot1", "--json", timeout=120
    )
    assert status.returncode == 0, status.stderr
    (row,) = json.loads(status.stdout)
    assert row["reachable"] and row["health"] == "healthy", row
    # daemon.json may hold proxy credentials: root's alone (issue 27, item 7).
    assert lab.ok("robot1", "stat -c %a:%U:%G /etc/docker/daemon.json").strip() == "600:root:root"

    # 4. The robot gets a new host key: enroll and the deploy refuse it, the file stays as it was.
    before = first_contact.known_hosts.read_text()
    lab.ok("robot1", "rm -f /etc/ssh/ssh_host_*; ssh-keygen -A >/dev/null; systemctl restart ssh")
    new_key = lab.ok(
        "robot1", f"cat /etc/ssh/ssh_host_{lines[0].split()[1].removeprefix('ssh-').split('-')[0]}_key.pub"
    )
    again = first_contact(
        "enroll robot1 after its key changed",
        "-m",
        "robotfleet",
        "enroll",
        "inventories/lab.py",
        "--limit",
        "robot1",
        "--yes",
        timeout=120,
    )
    assert again.returncode == 1, again.stderr
    old_print, new_print = fingerprint(lines[0]), fingerprint(f"x {new_key}")
    assert (
        f"robot1: host key CHANGED for {entry}: {first_contact.known_hosts} has {lines[0].split()[1]} {old_print}, "
        f"the host offers {lines[0].split()[1]} {new_print}; refused"
    ) in again.stderr
    assert first_contact.known_hosts.read_text() == before
    changed = first_contact("deploy after the key changed", *deploy, timeout=300)
    assert changed.returncode != 0
    assert (
        f"[robot1] host key CHANGED: {first_contact.known_hosts} has {old_print} for {entry}, "
        f"the host offers {new_print}; refused" in changed.stderr
    )
    assert first_contact.known_hosts.read_text() == before

    # 5. The robot was reflashed: with its new fingerprint recorded, --replace
    #    takes the new key and says what it replaced (issue 28, item 9).
    kind = lines[0].split()[1]
    fingerprints.write_text(f"robot1 {new_print}\n")
    replaced = first_contact(
        "enroll --replace robot1",
        "-m",
        "robotfleet",
        "enroll",
        "inventories/lab.py",
        "--replace",
        "robot1",
        "--fingerprints",
        str(fingerprints),
        timeout=120,
    )
    assert replaced.returncode == 0, replaced.stderr
    assert (
        f"robot1 ({entry}): host key replaced: was {kind} {old_print}, now {kind} {new_print} (matches {fingerprints})"
    ) in replaced.stderr
    assert first_contact.known_hosts.read_text().splitlines() == [f"{entry} {new_key.split()[0]} {new_key.split()[1]}"]
    again = first_contact(
        "status after the replace",
        "-m",
        "robotfleet",
        "status",
        "inventories/lab.py",
        "--limit",
        "robot1",
        "--json",
        timeout=120,
    )
    assert again.returncode == 0, again.stderr
