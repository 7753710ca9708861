"""End to end, host certificates (issue 27, item 13): a lab robot's host key
signed by a host CA, a known_hosts holding only the `@cert-authority` line;
`robotfleet status` and a pyinfra run connect with strict checking, and an
expired certificate, a wrong principal, a revoked key and another CA's
signature are each refused with one line naming the host and the reason,
the known_hosts file left as it was (no trust on first use).

    ROBOT_LAB_E2E_PREFIX=op .venv/bin/python -m pytest tests/e2e/test_hostcerts.py -q
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import pytest

from tests.e2e.conftest import ROOT, one_robot_lab, phase
from tests.fixtures import PYINFRA

pytestmark = pytest.mark.e2e


@pytest.fixture(scope="module")
def lab():
    """One robot whose sshd presents the certificates: no provisioning, only its sshd (a lab of its own)."""
    yield from one_robot_lab("hostcerts")


@pytest.fixture(scope="module")
def signed(lab, tmp_path_factory):
    """The robot's ed25519 key, a host CA and another CA; ``present(cert)``
    installs a certificate and waits until sshd shows it."""
    from tests.lab import hostcert

    base = tmp_path_factory.mktemp("hostcerts")
    ca = hostcert.make_ca(base, "fleet-host-ca")
    hostcert.make_ca(base, "another-ca")  # its certificate is refused (signed.base / "another-ca")
    key = hostcert.host_key(lab.prefix, "robot1")
    port = lab.state["hosts"][0]["port"]
    serials = iter(range(1, 100))

    def certificate(by=ca, principals=("127.0.0.1",), validity="-5m:+1h"):
        serial = next(serials)
        cert = hostcert.sign(by, key, base / "certs", "robot1", list(principals), validity, serial)
        hostcert.install(lab.prefix, "robot1", cert)
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:  # sshd re-executes on reload: wait for it to show this one
            scan = subprocess.run(["ssh-keyscan", "-c", "-p", str(port), "127.0.0.1"], capture_output=True, text=True)
            shown = subprocess.run(["ssh-keygen", "-Lf", "-"], input=scan.stdout, capture_output=True, text=True)
            if f"Serial: {serial}\n" in shown.stdout:
                return cert
            time.sleep(0.2)
        raise AssertionError(f"robot1's sshd does not show certificate serial {serial}")

    certificate.ca, certificate.base, certificate.port = ca, base, port
    yield certificate
    hostcert.remove(lab.prefix, "robot1")


@pytest.fixture
def fleet(lab, signed, tmp_path):
    """A known_hosts with only the CA line, and a fleet file naming a KRL."""
    known_hosts = tmp_path / "known_hosts"
    known_hosts.write_text(f"@cert-authority * {signed.ca.with_suffix('.pub').read_text()}")
    krl = tmp_path / "revoked.krl"
    subprocess.run(["ssh-keygen", "-q", "-k", "-f", str(krl)], check=True, input="", text=True)  # an empty KRL
    fleet_file = lab.fleet_with(
        tmp_path, **{"  vars:\n    ssh_user: ops\n": f"  vars:\n    ssh_user: ops\n    ssh_revoked_host_keys: {krl}\n"}
    )
    env = dict(
        os.environ,
        ROBOT_LAB_PREFIX=lab.prefix,
        ROBOT_LAB_KNOWN_HOSTS=str(known_hosts),
        ROBOT_LAB_FLEET=str(fleet_file),
        PYINFRA_PROGRESS="off",
    )

    def run(label: str, *argv: str) -> subprocess.CompletedProcess:
        started = time.monotonic()
        proc = subprocess.run([sys.executable, *argv], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
        phase(f"{label} (exit {proc.returncode})", started)
        return proc

    run.known_hosts, run.krl = known_hosts, krl
    return run


STATUS = ("-m", "robotfleet", "status", "inventories/lab.py", "--json")


def refusal(proc: subprocess.CompletedProcess) -> str:
    (row,) = json.loads(proc.stdout)
    # A host key not trusted is a failure, not an unreachable host (README, "Exit codes").
    assert row["reachable"] is False and proc.returncode == 1, proc.stderr
    lines = [line for line in proc.stderr.splitlines() if line.startswith("[robot1]")]
    assert len(lines) == 1 and lines[0] == f"[robot1] failed: {row['error']} (1/1)", proc.stderr
    return row["error"]


def test_a_certified_host_connects_with_only_the_ca_line(signed, fleet):
    signed()
    before = fleet.known_hosts.read_text()
    status = fleet("status with a valid certificate", *STATUS)
    assert status.returncode == 0, status.stderr
    (row,) = json.loads(status.stdout)
    assert row["reachable"] is True and row["arch"] == "amd64"
    # The pyinfra CLI through the same connector, strict checking on.
    run = fleet(
        "pyinfra exec with a valid certificate", "-c", PYINFRA, "-y", "inventories/lab.py", "exec", "--", "true"
    )
    assert run.returncode == 0, run.stderr[-3000:]
    assert fleet.known_hosts.read_text() == before  # nothing learnt on first use


def test_expired_wrong_principal_revoked_and_another_ca_are_each_refused_in_one_line(signed, fleet):
    from tests.lab import hostcert

    before = fleet.known_hosts.read_text()
    signed(validity="20200101:20200201")
    assert refusal(fleet("status, expired certificate", *STATUS)).startswith(
        "host certificate refused: its host certificate is invalid: expired (certificate 'robot1', serial "
    )

    signed(principals=("robot7",))
    assert refusal(fleet("status, wrong principal", *STATUS)).startswith(
        "host certificate refused: its host certificate is invalid: 127.0.0.1 is not one of its principals "
        "(certificate 'robot1', serial "
    )

    cert = signed()
    hostcert.revoke(cert, fleet.krl)
    assert refusal(fleet("status, revoked certificate", *STATUS)).startswith(
        f"host certificate refused: its host key is revoked by the KRL {fleet.krl} (certificate 'robot1', serial "
    )

    fleet.krl.unlink()
    subprocess.run(["ssh-keygen", "-q", "-k", "-f", str(fleet.krl)], check=True, input="", text=True)
    other = signed(by=signed.base / "another-ca")
    shown = subprocess.run(["ssh-keygen", "-Lf", str(other)], capture_output=True, text=True).stdout
    other_ca = shown.split("Signing CA: ", 1)[1].split()[1]
    assert refusal(fleet("status, another CA", *STATUS)).startswith(
        f"host certificate refused: its host certificate is signed by CA {other_ca}, which no @cert-authority line "
        f"of {fleet.known_hosts} trusts for it (certificate 'robot1', serial "
    )

    assert fleet.known_hosts.read_text() == before  # never trusted on first use
