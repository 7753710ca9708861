"""The fleet remote's rules on gitolite (robotfleet/pull/operator/gitolite.py) and the lab's git server."""

import re

import pytest

from robotfleet.pull.operator import gitolite

KEY = "ssh-ed25519 AAAAC3NzaC1lZDI1NTE5AAAAIGbigA6mqsYKDD3V4SGhrWodxIaju5HYfXtBYAQEvqW0"


def test_each_robot_may_write_only_its_own_report_ref():
    text = gitolite.conf("fleet", ["robot2", "robot1"])
    assert "@robots = robot1 robot2" in text
    assert "    R = @robots" in text
    assert "    RW+ refs/reports/robot1$ = robot1" in text
    assert "    RW+ refs/reports/robot2$ = robot2" in text
    # robots get no other write rule: the releases branch is the admin's alone
    writes = [line for line in text.splitlines() if line.strip().startswith("RW")]
    assert writes == ["    RW+ = admin", "    RW+ = admin",
                      "    RW+ refs/reports/robot1$ = robot1", "    RW+ refs/reports/robot2$ = robot2"]


def test_a_robot_name_is_matched_literally_not_as_a_pattern():
    text = gitolite.conf("fleet", ["r.1"])
    rule = next(line for line in text.splitlines() if "refs/reports/" in line)
    refex = rule.split()[1]
    assert re.match(refex, "refs/reports/r.1")
    assert not re.match(refex, "refs/reports/rx1")
    assert not re.match(refex, "refs/reports/r.10")


def test_no_robots_no_robot_rules():
    text = gitolite.conf("fleet", [])
    assert "@robots" not in text and "refs/reports" not in text
    assert "repo fleet\n    RW+ = admin\n" in text


@pytest.mark.parametrize("name", ["", "-x", "a/b", "robot 1", "a@enroll", "a\nb", 7])
def test_names_gitolite_cannot_take_are_refused(name):
    with pytest.raises(gitolite.GitoliteError, match="cannot be a gitolite user"):
        gitolite.conf("fleet", [name])


def test_key_files_of_own_and_enrollment_keys():
    assert gitolite.key_file("robot1") == "keydir/robot1.pub"
    assert gitolite.key_file("robot1", enrollment=True) == "keydir/robot1@enroll.pub"


def test_robots_are_read_back_from_the_key_directory(tmp_path):
    for name in ("robot1.pub", "robot1@enroll.pub", "robot2@enroll.pub", "admin.pub", "notes.txt"):
        (tmp_path / name).write_text(KEY)
    assert gitolite.robots_in(tmp_path) == {"robot1", "robot2", "admin"}


def test_a_public_key_is_one_line_without_its_comment():
    assert gitolite.check_key(f"\n{KEY} root@robot1\n", "k") == KEY
    for bad in ("", f"{KEY}\n{KEY}", "-----BEGIN OPENSSH PRIVATE KEY-----", "ssh-ed25519 AAA$$"):
        with pytest.raises(gitolite.GitoliteError, match="k: not one OpenSSH public key line"):
            gitolite.check_key(bad, "k")


def test_admin_uses_strict_host_keys_and_only_its_key():
    env = gitolite.Admin("ssh://gitolite3@h:2222", "/k/id", "/k/known").env()
    ssh = env["GIT_SSH_COMMAND"]
    for option in ("-i /k/id", "IdentitiesOnly=yes", "StrictHostKeyChecking=yes",
                   "UserKnownHostsFile=/k/known", "BatchMode=yes"):
        assert option in ssh


def test_lab_git_server_known_hosts_names_it_both_ways():
    from tests.lab import gitserver

    lines = gitserver.known_hosts_lines(["[127.0.0.1]:24001", "e2e-git"], [KEY + " root@git"])
    assert lines == [f"[127.0.0.1]:24001,e2e-git {KEY}"]


def test_lab_state_may_name_a_git_server(tmp_path):
    from tests.lab import state
    from tests.unit.test_lab_state import sample

    lab = dict(sample(), git={"container": "t-git", "port": 24001})
    state.save(lab, root=tmp_path)
    assert state.load("t", root=tmp_path)["git"]["port"] == 24001
