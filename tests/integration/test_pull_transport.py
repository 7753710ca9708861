"""The robot's side of the fleet remote (robotfleet/pull/robot/transport.py) on
real git repositories (file:// remotes: ssh is not needed to test git's
part), and what it reads from ssh's log."""

from __future__ import annotations

import datetime
import os
import subprocess

import pytest

from robotfleet.pull.operator import channel
from robotfleet.pull.protocol import reports
from robotfleet.pull.robot import remote_git, ssh_options, transport
from tests.integration.craftedgit import git

LOG = """Authenticated to git.lan ([10.0.0.5]:22) using "publickey".
debug1: Server accepts key: /etc/robot-pull/id_ed25519 ED25519 SHA256:abc explicit
Transferred: sent 3140, received 3364 bytes, in 0.1 seconds
Bytes per second: sent 31400.0, received 33640.0
"""


@pytest.fixture
def remote(tmp_path):
    """A bare fleet remote with a releases branch of one file."""
    bare = tmp_path / "fleet.git"
    subprocess.run(["git", "init", "-q", "--bare", str(bare)], check=True)
    work = tmp_path / "work"
    work.mkdir()
    git(work, "init", "-q")
    (work / "metadata").mkdir()
    (work / "metadata" / "timestamp.json").write_text("v1")
    git(work, "add", "-A")
    git(work, "commit", "-q", "-m", "one")
    git(work, "push", "-q", str(bare), "HEAD:refs/heads/robotfleet/releases")
    return bare, work


def report(robot: str, result: str = "applied") -> bytes:
    return reports.to_bytes(reports.build(robot, datetime.datetime(2026, 11, 25, tzinfo=datetime.timezone.utc), result))


def test_ssh_pins_the_server_and_offers_only_the_robot_s_keys():
    command = ssh_options.ssh_command(
        ["/etc/robot-pull/id_ed25519", "/etc/robot-pull/enroll_ed25519"], "/etc/robot-pull/known_hosts", "/tmp/log", 300
    )
    for part in (
        "-F /dev/null",
        "IdentitiesOnly=yes",
        "BatchMode=yes",
        "StrictHostKeyChecking=yes",
        "UserKnownHostsFile=/etc/robot-pull/known_hosts",
        "HostKeyAlias=robotfleet-remote",
        "ConnectTimeout=30",
        "-E /tmp/log",
        "-i /etc/robot-pull/id_ed25519 -i /etc/robot-pull/enroll_ed25519",
    ):
        assert part in command


def test_the_bytes_and_the_accepted_key_come_from_ssh_s_log():
    assert remote_git.read_ssh_log(LOG) == (3140, 3364, "/etc/robot-pull/id_ed25519")
    assert remote_git.read_ssh_log("") == (0, 0, None)


def test_the_telling_line_of_a_git_failure():
    said = (
        "gitolite3@git.lan: Permission denied (publickey).\r\nfatal: Could not read from remote repository.\n\n"
        "Please make sure you have the correct access rights\nand the repository exists.\n"
    )
    assert remote_git.git_error(said, 128) == "gitolite3@git.lan: Permission denied (publickey)."
    denied = "FATAL: W refs/reports/robot2 fleet robot1 DENIED by fallthru\n"
    assert remote_git.git_error(denied, 1).startswith("FATAL: W")
    assert remote_git.git_error("", 7) == "git exited 7"
    # ssh's line, from its log, when the server drops the connection before a login (OpenSSH 10's penalty)
    reset = (
        "fatal: Could not read from remote repository.\n\nPlease make sure...\nConnection reset by 172.19.0.4 port 22\n"
    )
    assert remote_git.git_error(reset, 128) == "Connection reset by 172.19.0.4 port 22"


def test_fetch_checks_out_the_releases_branch_and_follows_it(remote, tmp_path):
    bare, work = remote
    robot = transport.Remote(f"file://{bare}", tmp_path / "state" / "releases", str(tmp_path / "etc"), timeout=30)
    first = robot.fetch_releases()
    assert (robot.repo / "metadata" / "timestamp.json").read_text() == "v1"
    (robot.repo / "left-over").write_text("x")  # nothing but the commit is read later
    (work / "metadata" / "timestamp.json").write_text("v2")
    git(work, "commit", "-q", "-am", "two")
    git(work, "push", "-q", str(bare), "HEAD:refs/heads/robotfleet/releases")
    second = robot.fetch_releases()
    assert second != first and (robot.repo / "metadata" / "timestamp.json").read_text() == "v2"
    assert not (robot.repo / "left-over").exists()
    assert git(robot.repo, "rev-parse", "--is-shallow-repository").strip() == "true"


def test_a_missing_branch_is_one_line(tmp_path):
    bare = tmp_path / "empty.git"
    subprocess.run(["git", "init", "-q", "--bare", str(bare)], check=True)
    robot = transport.Remote(f"file://{bare}", tmp_path / "repo", str(tmp_path / "etc"), timeout=30)
    with pytest.raises(transport.TransportError, match=r"^fetch: fatal: couldn't find remote ref"):
        robot.fetch_releases()


def test_reports_are_pushed_as_one_file_commits_and_read_back_by_name(remote, tmp_path):
    bare, _ = remote
    robots = {
        name: transport.Remote(f"file://{bare}", tmp_path / name, str(tmp_path / "etc"), timeout=30)
        for name in ("robot1", "robot10", "robot2")
    }
    for name, robot in robots.items():
        robot.push_report(name, report(name))
    robots["robot1"].push_report("robot1", report("robot1", "waiting"))  # forced over the last
    assert git(bare, "ls-tree", "--name-only", "refs/reports/robot1").split() == ["report.json"]
    reader = transport.Remote(f"file://{bare}", tmp_path / "reader", str(tmp_path / "etc"), timeout=30)
    found = reader.fetch_reports(["robot1", "robot3"])
    assert list(found) == ["robot1"] and found["robot1"]["result"] == "waiting"  # robot10 matched by prefix, left out
    assert reader.fetch_reports([]) == {}


def test_the_enrollment_key_is_retired_once_the_robot_s_own_key_was_accepted(tmp_path):
    etc = tmp_path / "etc"
    etc.mkdir()
    for name in ("id_ed25519", "enroll_ed25519", "enroll_ed25519.pub"):
        (etc / name).write_text("k")
    robot = transport.Remote("file:///nowhere", tmp_path / "repo", str(etc))
    robot.accepted_key = str(etc / "enroll_ed25519")
    assert robot.retire_enrollment_key() is False and (etc / "enroll_ed25519").exists()
    robot.accepted_key = str(etc / "id_ed25519")
    assert robot.retire_enrollment_key() is True
    assert not (etc / "enroll_ed25519").exists() and not (etc / "enroll_ed25519.pub").exists()
    assert robot.keys() == [str(etc / "id_ed25519")]


@pytest.fixture(scope="module")
def tls(tmp_path_factory):
    from tests.integration import httpsgit

    return httpsgit.make_ca(tmp_path_factory.mktemp("tls"))


@pytest.fixture(params=["smart", "static"])
def https_remote(request, remote, tls, tmp_path):
    """The remote fixture's repository over HTTPS: git http-backend, or its
    files served as they are (a static "dumb" remote)."""
    from tests.integration import httpsgit

    bare, work = remote
    git(bare, "update-server-info")
    ca, cert, key = tls
    server = httpsgit.Server(bare.parent, cert, key, smart=request.param == "smart")
    etc = tmp_path / "etc"
    etc.mkdir()
    yield server, bare, work, etc, ca
    server.close()


def test_releases_are_fetched_over_https_with_the_fleet_s_ca_and_counted(https_remote, tmp_path):
    server, bare, work, etc, ca = https_remote
    robot = transport.Remote(server.url("fleet.git"), tmp_path / "releases", str(etc), timeout=30)
    with pytest.raises(transport.TransportError, match=r"^fetch: .*certificate verif"):
        robot.fetch_releases()  # the self-signed CA is not the system's: refused
    (etc / "remote-ca.pem").write_bytes(ca.read_bytes())
    robot = transport.Remote(server.url("fleet.git"), tmp_path / "releases", str(etc), timeout=30)
    before = server.requests
    first = robot.fetch_releases()
    assert (robot.repo / "metadata" / "timestamp.json").read_text() == "v1"
    assert robot.cost.requests == server.requests - before and robot.cost.requests >= 2
    assert robot.cost.received > 300 and robot.cost.sent > 100
    (work / "metadata" / "timestamp.json").write_text("v2")
    git(work, "commit", "-q", "-am", "two")
    git(work, "push", "-q", str(bare), "HEAD:refs/heads/robotfleet/releases")
    git(bare, "update-server-info")
    assert robot.fetch_releases() != first
    assert (robot.repo / "metadata" / "timestamp.json").read_text() == "v2"
    shallow = git(robot.repo, "rev-parse", "--is-shallow-repository").strip()
    assert shallow == ("true" if server.smart else "false")  # a static remote cannot answer a shallow fetch


def test_reports_go_to_the_report_remote_while_releases_come_over_https(https_remote, tmp_path):
    server, bare, work, etc, ca = https_remote
    (etc / "remote-ca.pem").write_bytes(ca.read_bytes())
    elsewhere = tmp_path / "reports.git"
    subprocess.run(["git", "init", "-q", "--bare", str(elsewhere)], check=True)
    robot = transport.Remote(
        server.url("fleet.git"), tmp_path / "releases", str(etc), timeout=30, report_url=f"file://{elsewhere}"
    )
    robot.fetch_releases()
    robot.push_report("robot1", report("robot1"))
    assert git(elsewhere, "show", "refs/reports/robot1:report.json") == report("robot1").decode().strip()
    assert "refs/reports" not in git(bare, "for-each-ref")
    git(elsewhere, "push", "-q", str(bare), "refs/reports/robot1:refs/reports/robot2")  # as robot2 pushed it
    git(bare, "update-server-info")
    if server.smart:  # the earlier waves' reports are read from the releases' remote, over HTTPS too
        assert robot.fetch_reports(["robot2"]) == {
            "robot2": {"robot": "robot2", "error": "report of robot2: names another robot (robot1)"}
        }


def test_links_on_the_releases_branch_are_checked_out_as_files(remote, tmp_path):
    # A hostile git server (or whoever can push the branch) commits links:
    # the next root to /dev/zero, the timestamp to a file of the robot's own,
    # and targets/ to a directory elsewhere.
    bare, work = remote
    secret = tmp_path / "hostname"
    secret.write_text("robot-secret\n")
    (work / "metadata" / "timestamp.json").unlink()
    (work / "metadata" / "timestamp.json").symlink_to(secret)
    (work / "metadata" / "2.root.json").symlink_to("/dev/zero")
    (work / "targets").symlink_to(tmp_path)
    git(work, "add", "-A")
    git(work, "commit", "-q", "-m", "links")
    git(work, "push", "-q", str(bare), "HEAD:refs/heads/robotfleet/releases")
    assert git(bare, "ls-tree", "robotfleet/releases", "targets").startswith("120000 blob")
    robot = transport.Remote(f"file://{bare}", tmp_path / "state" / "releases", str(tmp_path / "etc"), timeout=30)
    robot.fetch_releases()
    links = [
        os.path.join(where, name)
        for where, dirs, files in os.walk(robot.repo)
        for name in dirs + files
        if os.path.islink(os.path.join(where, name))
    ]
    assert links == []
    # what the trusted-metadata reader reads there is the links' text, never what they point at
    assert (robot.repo / "metadata" / "timestamp.json").read_bytes() == str(secret).encode()
    assert (robot.repo / "metadata" / "2.root.json").read_bytes() == b"/dev/zero"
    assert (robot.repo / "targets").is_file()
    # nor does the operator's publishing clone of the branch hold them
    clone = channel.GitChannel(tmp_path, str(bare), clone=tmp_path / "publishing").open()
    assert not any(
        os.path.islink(os.path.join(where, name)) for where, dirs, files in os.walk(clone) for name in dirs + files
    )
    assert (clone / "metadata" / "2.root.json").read_bytes() == b"/dev/zero"


def test_a_read_of_many_robots_asks_for_every_report_and_reads_only_the_robots_asked(remote, tmp_path, monkeypatch):
    """Past PREFIXES_AT_MOST robots the read is one refspec for the whole
    repository (git matches every refspec against every ref: 7,500 prefixes
    cost 31 s of CPU at 10,000 robots), and still only the robots asked for
    are read, each under its own name."""
    bare, _ = remote
    names = ("robot1", "robot10", "robot2", "robot3")
    for name in names:
        transport.Remote(f"file://{bare}", tmp_path / name, str(tmp_path / "etc"), timeout=30).push_report(
            name, report(name)
        )
    for at_most in (1, 256):
        monkeypatch.setattr(transport, "PREFIXES_AT_MOST", at_most)
        reader = transport.Remote(f"file://{bare}", tmp_path / f"reader{at_most}", str(tmp_path / "etc"), timeout=30)
        found = reader.fetch_reports(["robot1", "robot3", "robot9"])
        assert sorted(found) == ["robot1", "robot3"] and found["robot3"]["robot"] == "robot3"
        assert reader.fetch_reports(["robot1", "robot3", "robot9"]) == found  # again, from what it kept
