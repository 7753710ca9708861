"""robotfleet pull-enroll (issue 36, item 5): nothing in a robot's report is
taken on its word.  Real git repositories (the robots' reports pushed to
refs/reports/<robot> of a bare fleet remote), real keys and signatures
(ssh-keygen -Y sign on the robot's side, as the agent makes them; -Y verify
on the operator's), the command run as the operator runs it."""

from __future__ import annotations

import json
import os
import pty
import subprocess
import sys

import paramiko
import pytest

from robotfleet import hostkeys
from robotfleet.commands.pull import enroll as pullenroll
from robotfleet.pull.operator import bundle, enrollments
from robotfleet.pull.protocol import enrollment, reports
from robotfleet.pull.robot import enrollment_proof
from tests.fixtures import ROOT
from tests.integration.operator_side import fleet
from tests.unit.pullkit import NOW

SERVER = "ssh-ed25519 AAAAC3NzaC1lZDI1NTE5AAAAIGbigA6mqsYKDD3V4SGhrWodxIaju5HYfXtBYAQEvqW0"
ENV = {
    "GIT_AUTHOR_NAME": "robot",
    "GIT_AUTHOR_EMAIL": "robot@x",
    "GIT_COMMITTER_NAME": "robot",
    "GIT_COMMITTER_EMAIL": "robot@x",
}


def keypair(path) -> str:
    """A new ed25519 key at ``path`` (ssh-keygen); its public line (type and base64)."""
    subprocess.run(["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-f", str(path)], check=True)
    return keypair_line(path)


def keypair_line(path) -> str:
    with open(f"{path}.pub") as public:
        return " ".join(public.read().split()[:2])


def line_of(key) -> str:
    return f"{key.get_name()} {key.get_base64()}"


class Site:
    """A fleet remote, the operator's files and a robot (robot9) with its keys."""

    def __init__(self, tmp_path, monkeypatch):
        self.base = tmp_path
        self.remote = tmp_path / "fleet.git"
        subprocess.run(["git", "init", "-q", "--bare", str(self.remote)], check=True)
        self.known_hosts = tmp_path / "known_hosts"
        self.kept = tmp_path / "enrollments.json"
        self.fleet = fleet(
            tmp_path,
            {
                name: {"address": "127.0.0.1", "ssh_port": port, "pull_enabled": True}
                for name, port in (("robot9", 2209), ("robot-0123456789ab", 2210))
            },
            pull_remote="ssh://gitolite3@git.lan/fleet",
            pull_remote_host_keys=[SERVER],
            ssh_known_hosts_file=str(self.known_hosts),
        )
        monkeypatch.setenv("ROBOT_FLEET", str(self.fleet))
        monkeypatch.setenv(enrollments.ENV, str(self.kept))
        monkeypatch.chdir(ROOT)
        self.bundle_key = tmp_path / "enroll_ed25519"  # what robot9's bundle carries
        bundle.remember(self.kept, "robot9", keypair(self.bundle_key), 3)
        self.host_key = paramiko.ECDSAKey.generate()
        self.own = keypair(tmp_path / "id_ed25519")

    def report(self, robot="robot9", signer=None, key=None, host_keys=None, **more) -> dict:
        """A report as robot's agent builds it, signed by ``signer`` (a private key file; None: no proof)."""
        key = key or self.own
        hosts = [line_of(self.host_key)] if host_keys is None else host_keys
        proof = enrollment_proof.proof(str(signer), robot, key, hosts, {}) if signer else None
        made = reports.build(robot, NOW, "applied", host_keys=hosts, key=key, enrollment=proof)
        made.update(more)
        return made

    def push(self, report: dict, robot="robot9") -> None:
        """The report at refs/reports/<robot>, as a robot's push leaves it."""

        def git(*args, data=None):
            return subprocess.run(
                ["git", "-C", str(self.remote), *args],
                input=data,
                capture_output=True,
                check=True,
                env={**os.environ, **ENV},
            ).stdout.strip()

        blob = git("hash-object", "-w", "--stdin", data=reports.to_bytes(report)).decode()
        tree = git("mktree", data=f"100644 blob {blob}\treport.json\n".encode()).decode()
        git("update-ref", f"refs/reports/{robot}", git("commit-tree", tree, "-m", "report").decode())

    def enroll(self, capsys, *args) -> tuple[int, str, str]:
        code = pullenroll.main(["inventories/robots.py", "--remote", f"file://{self.remote}", *args])
        out, err = capsys.readouterr()
        return code, out, err

    def enrolled(self, robot="robot9", port=2209) -> dict:
        return hostkeys.known(str(self.known_hosts), f"[127.0.0.1]:{port}")

    def kept_key(self, robot="robot9"):
        return enrollments.enrolled_key(enrollments.read_kept(self.kept), robot)


@pytest.fixture
def site(tmp_path, monkeypatch):
    return Site(tmp_path, monkeypatch)


def test_a_report_proven_by_its_bundle_s_enrollment_key_is_enrolled(site, capsys):
    site.push(site.report(signer=site.bundle_key))
    code, out, err = site.enroll(capsys, "--limit", "robot9")
    assert code == 0, err
    assert "robot9: its report is proven by its bundle's enrollment key" in out
    assert "from its report; enrolled in" in out and f"robot9: its key for the fleet remote: {site.own}" in out
    assert site.enrolled() == {"ecdsa-sha2-nistp256": site.host_key}
    assert site.kept_key() == enrollment.key_sha256(site.own)
    code, out, err = site.enroll(capsys, "--limit", "robot9")  # again: nothing new
    assert code == 0 and "already in" in out, err


def forged(site, how: str) -> dict:
    other = site.base / "other_ed25519"
    keypair(other)
    if how == "no proof":
        return site.report()
    if how == "signed by a key of its own":
        return site.report(signer=other)
    if how == "signed by another key, naming the bundle's":
        report = site.report(signer=other)
        report["enrollment"]["key"] = keypair_line(site.bundle_key)
        return report
    if how == "another robot's bundle":
        bundle.remember(site.kept, "robot8", keypair_line(other), 3)
        return site.report(signer=other)
    if how == "host keys changed after signing":
        report = site.report(signer=site.bundle_key)
        report["host_keys"] = [line_of(paramiko.ECDSAKey.generate())]
        return report
    raise AssertionError(how)


@pytest.mark.parametrize(
    "how, why",
    [
        ("no proof", "its report carries no enrollment proof"),
        ("signed by a key of its own", "its report is signed by an enrollment key {kept} does not keep for robot9"),
        ("signed by another key, naming the bundle's", "its enrollment proof does not verify"),
        ("another robot's bundle", "its report is signed by an enrollment key {kept} does not keep for robot9"),
        ("host keys changed after signing", "its enrollment proof does not verify"),
    ],
)
def test_a_forged_first_report_is_not_enrolled(site, capsys, how, why):
    site.push(forged(site, how))
    code, out, err = site.enroll(capsys, "--limit", "robot9")
    assert code == 1, out + err
    line = next(line for line in err.splitlines() if line.startswith("robot9: not enrolled: "))
    assert why.format(kept=site.kept) in line and "give --fingerprints FILE" in line
    assert not site.known_hosts.exists()  # nothing written, not even an empty file
    assert site.kept_key() is None and "its key for the fleet remote" not in out


def test_a_name_reported_again_with_another_key_is_refused_until_the_operator_replaces_it(site, capsys):
    site.push(site.report(signer=site.bundle_key))
    assert site.enroll(capsys, "--limit", "robot9")[0] == 0
    before = site.known_hosts.read_text()
    # whoever else holds a copy of the bundle reports as robot9, its proof valid
    intruder = keypair(site.base / "intruder_ed25519")
    site.push(site.report(signer=site.bundle_key, key=intruder, host_keys=[line_of(paramiko.ECDSAKey.generate())]))
    code, out, err = site.enroll(capsys, "--limit", "robot9")
    assert code == 1
    assert (
        f"robot9: reported with its own key ssh-ed25519 {hostkeys.fingerprint(pullenroll.key_of(intruder))}, but "
        f"it was enrolled with another ({site.kept}); refused: if robot9 was reinstalled, robotfleet pull-enroll "
        "inventories/robots.py --replace robot9 with its new bundle's proof or --fingerprints FILE"
    ) in err
    assert site.known_hosts.read_text() == before and site.kept_key() == enrollment.key_sha256(site.own)
    # the operator decides: robot9 was reflashed, its new keys read on its console
    new_host = paramiko.ECDSAKey.generate()
    site.push(site.report(key=intruder, host_keys=[line_of(new_host)]))
    recorded = site.base / "fingerprints.txt"
    recorded.write_text(
        f"robot9 {hostkeys.fingerprint(new_host)} {hostkeys.fingerprint(pullenroll.key_of(intruder))}\n"
    )
    code, out, err = site.enroll(capsys, "--limit", "robot9", "--replace", "robot9")
    assert code == 1 and "--replace robot9 needs its own bundle's proof or --fingerprints FILE" in err
    code, out, err = site.enroll(capsys, "--limit", "robot9", "--replace", "robot9", "--fingerprints", str(recorded))
    assert code == 0, err
    assert "host keys replaced" in out and site.enrolled() == {"ecdsa-sha2-nistp256": new_host}
    assert site.kept_key() == enrollment.key_sha256(intruder)


def test_a_fingerprints_file_must_list_every_key_of_the_report(site, capsys):
    site.push(site.report())
    recorded = site.base / "fingerprints.txt"
    recorded.write_text(f"robot9 {hostkeys.fingerprint(site.host_key)}\n")  # the own key missing
    code, out, err = site.enroll(capsys, "--limit", "robot9", "--fingerprints", str(recorded))
    assert code == 1 and "robot9: own key ssh-ed25519 " in err and f"not in {recorded}; refused" in err
    assert not site.known_hosts.exists()
    recorded.write_text(
        f"# read on its console\nrobot9 {hostkeys.fingerprint(site.host_key)} "
        f"{hostkeys.fingerprint(pullenroll.key_of(site.own))}\n"
    )
    code, out, err = site.enroll(capsys, "--limit", "robot9", "--fingerprints", str(recorded))
    assert code == 0 and f"robot9: its report's keys match {recorded}" in out, err
    assert site.enrolled() == {"ecdsa-sha2-nistp256": site.host_key}


def test_a_shared_image_s_key_proves_only_the_names_its_rule_makes(site, capsys):
    image = site.base / "image_ed25519"
    bundle.remember(site.kept, "enroll+machine-id+robot-", keypair(image), 3)
    site.push(site.report("robot-0123456789ab", signer=image), "robot-0123456789ab")
    site.push(site.report(signer=image))  # robot9 is no name the rule makes
    code, out, err = site.enroll(capsys)
    assert code == 1
    assert (
        "robot-0123456789ab: its report is proven by a shared image's enrollment key (whoever holds a copy of "
        "the image could have sent it)"
    ) in out
    assert f"robot9: not enrolled: its report is signed by an enrollment key {site.kept} does not keep" in err
    assert site.kept_key("robot-0123456789ab") and site.kept_key() is None


def test_a_report_whose_key_is_no_key_is_one_line(site, capsys):
    site.push(site.report(key="ssh-ed25519 AAAA"))
    code, out, err = site.enroll(capsys, "--limit", "robot9")
    assert code == 1 and "robot9: its report's keys cannot be read" in err


def test_on_a_terminal_the_operator_confirms_the_fingerprints(site):
    site.push(site.report())
    command = [
        sys.executable,
        "-m",
        "robotfleet",
        "pull-enroll",
        "inventories/robots.py",
        "--limit",
        "robot9",
        "--remote",
        f"file://{site.remote}",
    ]
    for answer, code in ((b"n\n", 1), (b"y\n", 0)):
        primary, secondary = pty.openpty()
        done = subprocess.Popen(command, stdin=secondary, stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=ROOT)
        os.close(secondary)
        os.write(primary, answer)
        out, err = done.communicate(timeout=120)
        os.close(primary)
        assert done.returncode == code, err
        assert f"robot9: ecdsa-sha2-nistp256 {hostkeys.fingerprint(site.host_key)}" in err.decode()
        assert "Are these robot9's keys (as its console shows them)? [y/N]" in err.decode()
    assert site.enrolled() == {"ecdsa-sha2-nistp256": site.host_key}
    assert json.loads(site.kept.read_text())["robot9"]["key_sha256"] == enrollment.key_sha256(site.own)
