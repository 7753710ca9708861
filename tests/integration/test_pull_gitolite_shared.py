"""Enrolling robots on a gitolite a team shares (robotfleet/pull/operator/gitolite.py
update, gitolite_admin.py), against Debian's real gitolite3
(tests/integration/gitoliteserver.py): an admin repository with two other
repositories, their users (one key in a subdirectory of keydir) and a
team's own ``@robots`` group.  After robots are enrolled every line of
gitolite.conf and every key is as it was (one include line appended), each
colleague keeps exactly the access they had and reads no fleet repository,
and the robots read the fleet and write only their own report refs, as
gitolite itself decides.  Layouts robotfleet cannot add to safely are
refused in one line with nothing pushed, and an older robotfleet's layout
(gitolite.conf written whole) is moved to the new one with its robots
still enrolled."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import pytest

from robotfleet.pull.operator import gitolite, gitolite_admin
from tests.integration.gitoliteserver import INSTALLED, GitoliteServer, git_as, new_key

pytestmark = pytest.mark.skipif(not INSTALLED, reason="needs Debian's gitolite3 (.ci/setup installs it)")

TEAM_CONF = """repo gitolite-admin
    RW+     =   admin

repo testing
    RW+     =   @all

# the team's own group, named as robotfleet's once was
@robots = carol

repo team-app
    RW+ = alice
    R   = @robots

repo team-docs
    RW  = bob
    R   = alice
"""
TEAM_KEYS = ("keydir/alice.pub", "keydir/bob.pub", "keydir/people/carol.pub")


class Shared:
    """A gitolite3 serving a team's team-app and team-docs, its admin's clone at hand."""

    def __init__(self, base: Path):
        self.base = base
        self.keys = {name: new_key(base / name) for name in ("admin", "alice", "bob", "carol", "robot1", "robot2")}
        self.server = GitoliteServer(base / "server", self.keys["admin"])
        self.known_hosts = self.server.known_hosts(base / "known_hosts")
        self.admin = gitolite.Admin(self.server.url, str(self.keys["admin"]), self.known_hosts)
        self.reset()

    def reset(self) -> None:
        """The admin repository as the team has it, before any robot."""
        self.edit(lambda work: self.team(work), "the team's repositories")
        self.files = self.admin_files()

    def team(self, work: Path) -> None:
        subprocess.run(["rm", "-rf", str(work / "conf"), str(work / "keydir")], check=True)
        (work / "conf").mkdir()
        (work / "conf" / "gitolite.conf").write_text(TEAM_CONF)
        for path in ("keydir/admin.pub", *TEAM_KEYS):
            (work / path).parent.mkdir(parents=True, exist_ok=True)
            (work / path).write_text(Path(f"{self.keys[Path(path).stem]}.pub").read_text())

    def git(self, who: str, *args: str, cwd=None) -> subprocess.CompletedProcess:
        return git_as(self.keys[who], self.known_hosts, *args, cwd=cwd)

    def edit(self, change, message: str) -> None:
        """The admin's own change of the admin repository, pushed."""
        work = self.base / "edit"
        subprocess.run(["rm", "-rf", str(work)], check=True)
        assert self.git("admin", "clone", "-q", f"{self.server.url}/gitolite-admin", str(work)).returncode == 0
        change(work)
        steps = (("add", "-A"), ("commit", "-qm", message, "--allow-empty"), ("push", "-q", "origin", "HEAD:master"))
        for args in steps:
            done = self.git("admin", *args, cwd=work)
            assert done.returncode == 0, done.stderr

    def admin_files(self) -> dict[str, str]:
        """Every file of the admin repository's master, as the server has it."""
        repo = self.server.repository("gitolite-admin")
        listed = ["git", "-C", str(repo), "ls-tree", "-r", "--name-only", "master"]
        names = subprocess.run(listed, check=True, capture_output=True, text=True).stdout.split()
        return {name: self.show(name) for name in names}

    def show(self, name: str) -> str:
        repo = self.server.repository("gitolite-admin")
        return subprocess.run(["git", "-C", str(repo), "show", f"master:{name}"], capture_output=True, text=True).stdout

    def head(self) -> str:
        repo = self.server.repository("gitolite-admin")
        return subprocess.run(["git", "-C", str(repo), "rev-parse", "master"], capture_output=True, text=True).stdout

    def enroll(self, robot: str, **options) -> bool:
        return gitolite.register(self.admin, "fleet", robot, Path(f"{self.keys[robot]}.pub").read_text(), **options)

    def reads(self, who: str, repo: str) -> bool:
        return self.git(who, "ls-remote", f"{self.server.url}/{repo}").returncode == 0

    def pushes(self, who: str, repo: str, ref: str) -> bool:
        work = self.base / f"push-{who}"
        if not (work / ".git").exists():
            subprocess.run(["git", "init", "-q", str(work)], check=True)
            (work / "report.json").write_text('{"robot": "%s"}\n' % who)
            assert self.git(who, "add", "report.json", cwd=work).returncode == 0
            assert self.git(who, "commit", "-qm", "a report", cwd=work).returncode == 0
        return self.git(who, "push", "-q", "-f", f"{self.server.url}/{repo}", f"HEAD:{ref}", cwd=work).returncode == 0


@pytest.fixture(scope="module")
def server(tmp_path_factory) -> Shared:
    server = Shared(tmp_path_factory.mktemp("shared-gitolite"))
    yield server
    server.server.close()


@pytest.fixture
def shared(server) -> Shared:
    server.reset()
    return server


def test_enrolling_robots_leaves_every_other_rule_and_key_as_it_was(shared):
    assert shared.enroll("robot1") and shared.enroll("robot2")
    assert gitolite.update(shared.admin, "fleet", message="two report shards", shards=2)
    after = shared.admin_files()
    conf = after.pop("conf/gitolite.conf")
    assert conf.startswith(TEAM_CONF) and conf[len(TEAM_CONF) :].strip().splitlines()[-1] == gitolite_admin.INCLUDE
    assert {name: after[name] for name in shared.files if name != "conf/gitolite.conf"} == {
        name: text for name, text in shared.files.items() if name != "conf/gitolite.conf"
    }  # every key as it was
    assert sorted(set(after) - set(shared.files)) == [
        "conf/robotfleet/fleet.conf",
        "keydir/robotfleet/fleet/robot1.pub",
        "keydir/robotfleet/fleet/robot2.pub",
    ]
    # the colleagues, as gitolite decides: what they had, and no fleet repository
    assert shared.pushes("alice", "team-app", "refs/heads/main")
    assert shared.pushes("bob", "team-docs", "refs/heads/main")
    assert shared.reads("carol", "team-app") and not shared.pushes("carol", "team-app", "refs/heads/carol")
    for colleague in ("alice", "bob", "carol"):
        assert not shared.reads(colleague, "fleet") and not shared.reads(colleague, "fleet-reports-0"), colleague
        assert not shared.pushes(colleague, "fleet", f"refs/reports/{colleague}"), colleague
    # the robots: the fleet and its shards, their own report refs, nothing of the team's
    for robot in ("robot1", "robot2"):
        assert shared.reads(robot, "fleet") and shared.reads(robot, "fleet-reports-1"), robot
        assert shared.pushes(robot, "fleet", f"refs/reports/{robot}"), robot
        assert not shared.reads(robot, "team-app") and not shared.reads(robot, "team-docs"), robot
    assert not shared.pushes("robot1", "fleet", "refs/reports/robot2")
    assert not shared.pushes("robot1", "fleet", "refs/heads/robotfleet/releases")
    assert not shared.enroll("robot1", shards=2)  # nothing new: nothing pushed


def refused(shared, change, message: str, robot: str = "robot1") -> str:
    shared.edit(change, message)
    before = shared.head()
    with pytest.raises(gitolite.GitoliteError) as error:
        shared.enroll(robot)
    assert shared.head() == before  # nothing pushed
    line = str(error.value)
    assert "\n" not in line and line.startswith(f"{shared.server.url}/gitolite-admin: "), line
    return line.split(": ", 1)[1]


def test_a_robot_named_as_a_colleague_is_refused_not_given_their_rules(shared):
    line = refused(shared, lambda work: None, "nothing", robot="alice")
    assert line.startswith("robot alice: keydir/alice.pub is already the gitolite user alice"), line
    assert shared.pushes("alice", "team-app", "refs/heads/main")


def test_layouts_robotfleet_cannot_add_to_safely_are_refused_in_one_line(shared, tmp_path):
    elsewhere = tmp_path / "operator-ssh"
    elsewhere.mkdir()

    def link(work):
        (work / "keydir" / "robotfleet").symlink_to(elsewhere)

    assert refused(shared, link, "a link").startswith("keydir/robotfleet: a symbolic link where robotfleet writes")
    assert list(elsewhere.iterdir()) == []  # nothing written through it on the operator's machine

    def unlink_and_own_file(work):
        (work / "keydir" / "robotfleet").unlink()
        (work / "conf" / "robotfleet").mkdir()
        (work / "conf" / "robotfleet" / "fleet.conf").write_text("repo fleet\n    RW+ = @all\n")

    assert refused(shared, unlink_and_own_file, "someone's file") == (
        "conf/robotfleet/fleet.conf: not written by robotfleet; move it away first"
    )

    def group(work):
        (work / "conf" / "robotfleet" / "fleet.conf").unlink()
        with (work / "conf" / "gitolite.conf").open("a") as conf:
            conf.write("@robotfleet-fleet = alice\n")

    assert refused(shared, group, "the fleet's group").startswith("conf/gitolite.conf: defines @robotfleet-fleet")


OLD_CONF = """# Written by robotfleet (robotfleet/pull/operator/gitolite.py); edits here are replaced.
repo gitolite-admin
    RW+ = admin

@robots = robot1

repo fleet
    RW+ = admin
    R = @robots
    RW+ refs/reports/robot1$ = robot1
"""


def test_an_older_robotfleet_s_layout_is_moved_with_its_robots_still_enrolled(shared):
    def old(work):
        for path in TEAM_KEYS:
            (work / path).unlink()
        (work / "conf" / "gitolite.conf").write_text(OLD_CONF)
        (work / "keydir" / "robot1.pub").write_text(Path(f"{shared.keys['robot1']}.pub").read_text())

    shared.edit(old, "as an older robotfleet wrote it")
    assert shared.pushes("robot1", "fleet", "refs/reports/robot1")
    assert shared.enroll("robot2")
    files = shared.admin_files()
    assert files["conf/gitolite.conf"].startswith("repo gitolite-admin\n    RW+ = admin\n"), files["conf/gitolite.conf"]
    assert gitolite_admin.INCLUDE in files["conf/gitolite.conf"] and "@robots" not in files["conf/gitolite.conf"]
    assert "keydir/robot1.pub" not in files and "keydir/robotfleet/fleet/robot1.pub" in files
    message = subprocess.run(
        ["git", "-C", str(shared.server.repository("gitolite-admin")), "log", "-1", "--format=%s", "master"],
        capture_output=True,
        text=True,
    ).stdout
    assert "older layout's robots moved to keydir/robotfleet/fleet: robot1" in message, message
    for robot in ("robot1", "robot2"):
        assert shared.reads(robot, "fleet") and shared.pushes(robot, "fleet", f"refs/reports/{robot}"), robot


def test_a_server_whose_rc_lets_no_rule_set_a_push_s_size_refuses_the_change_and_undoes_it(shared):
    rc = shared.server.home / ".gitolite.rc"
    text = rc.read_text()
    rc.write_text(text.replace("'receive.maxInputSize'", "''"))  # gitolite's default: no git config from rules
    try:
        with pytest.raises(gitolite.GitoliteError) as error:
            shared.enroll("robot1")
        line = str(error.value)
        assert "\n" not in line and "GIT_CONFIG_KEYS" in line and "(undone)" in line, line
        assert shared.admin_files() == shared.files  # the admin repository as it was
        assert shared.pushes("alice", "team-app", "refs/heads/main")  # gitolite's rules still compiled
    finally:
        rc.write_text(text)


# -- what the server takes from a robot: files/git-server/pre-receive, receive.maxInputSize --


def robot(shared, name: str, shards: int):
    """The pull agent's own transport (robotfleet/pull/robot/transport.py) as robot ``name``."""
    from robotfleet.pull.robot.transport import Remote

    etc = shared.base / f"etc-{name}"
    etc.mkdir(exist_ok=True)
    for suffix in ("", ".pub"):
        (etc / f"id_ed25519{suffix}").write_bytes(Path(f"{shared.keys[name]}{suffix}").read_bytes())
    (etc / "id_ed25519").chmod(0o600)
    key = shared.server.host_key
    (etc / "known_hosts").write_text(f"robotfleet-remote {key.get_name()} {key.get_base64()}\n")
    return Remote(f"{shared.server.url}/fleet", shared.base / f"releases-{name}", str(etc), 60, shards=shards)


def server_report(shared, repo: str, name: str) -> str:
    done = subprocess.run(
        ["git", "-C", str(shared.server.repository(repo)), "show", f"refs/reports/{name}:report.json"],
        capture_output=True,
        text=True,
    )
    return done.stdout


def test_a_robot_s_oversized_or_misshapen_report_is_refused_where_it_arrives(shared):
    from robotfleet.pull.protocol import reports
    from robotfleet.pull.robot.transport import TransportError

    assert shared.enroll("robot1", shards=2) and shared.enroll("robot2", shards=2)
    assert shared.pushes("admin", "fleet", "refs/heads/robotfleet/releases")  # a fleet repository: it has releases
    for repo, size in (("fleet", "1g"), ("fleet-reports-0", "1m"), ("fleet-reports-1", "1m")):
        config = ["git", "-C", str(shared.server.repository(repo)), "config", "receive.maxInputSize"]
        assert subprocess.run(config, capture_output=True, text=True).stdout.strip() == size, repo
    small = {"robot": "robot1", "result": "applied"}
    one, two = robot(shared, "robot1", 0), robot(shared, "robot2", 2)
    one.push_report("robot1", reports.to_bytes(small))
    two.push_report("robot2", reports.to_bytes({**small, "robot": "robot2"}))
    # 20 MiB that compress to almost nothing (no receive.maxInputSize stops them): the hook does
    with pytest.raises(TransportError) as error:
        one.push_report("robot1", reports.to_bytes({**small, "log": " " * (20 << 20)}))
    assert "robotfleet: refs/reports/robot1: report.json of 20971" in str(error.value), error.value
    # 2 MiB that do not compress: its shard cuts the push off as it arrives
    with pytest.raises(TransportError) as error:
        two.push_report("robot2", reports.to_bytes({**small, "robot": "robot2", "log": os.urandom(1 << 20).hex()}))
    assert "pack exceeds maximum allowed size" in str(error.value), error.value
    # misshapen: a report with a parent, a tree of two files
    work = shared.base / "push-robot1"
    (work / "extra.txt").write_text("more\n")
    assert shared.git("robot1", "add", "extra.txt", cwd=work).returncode == 0
    assert shared.git("robot1", "commit", "-qm", "two files", cwd=work).returncode == 0
    said = shared.git("robot1", "push", "-f", f"{shared.server.url}/fleet", "HEAD:refs/reports/robot1", cwd=work)
    assert "robotfleet: refs/reports/robot1: a commit with a parent" in said.stderr, said.stderr
    tree = shared.git("robot1", "write-tree", cwd=work).stdout.strip()
    lone = shared.git("robot1", "commit-tree", tree, "-m", "two files, no parent", cwd=work).stdout.strip()
    said = shared.git("robot1", "push", "-f", f"{shared.server.url}/fleet", f"{lone}:refs/reports/robot1", cwd=work)
    assert "its tree is not one report.json file" in said.stderr, said.stderr
    # every reader still finds each robot's last report the server took, and only it
    assert json.loads(server_report(shared, "fleet", "robot1")) == small
    assert json.loads(server_report(shared, "fleet-reports-1", "robot2")) == {**small, "robot": "robot2"}
