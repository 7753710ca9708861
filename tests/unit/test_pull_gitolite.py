"""The fleet remote's rules on gitolite (robotfleet/pull/operator/gitolite.py) and the lab's git server."""

import re

import pytest

from robotfleet.pull.operator import gitolite

KEY = "ssh-ed25519 AAAAC3NzaC1lZDI1NTE5AAAAIGbigA6mqsYKDD3V4SGhrWodxIaju5HYfXtBYAQEvqW0"


def test_each_robot_may_write_only_its_own_report_ref():
    text = gitolite.conf("fleet", ["robot2", "robot1"])
    assert "@robotfleet-fleet = robot1 robot2" in text  # the fleet's own group, never a team's @robots
    assert "    R = @robotfleet-fleet" in text
    assert "    RW+ refs/reports/robot1$ = robot1" in text
    assert "    RW+ refs/reports/robot2$ = robot2" in text
    # robots get no other write rule: the releases branch is the admin's alone
    writes = [line for line in text.splitlines() if line.strip().startswith("RW")]
    assert writes == [  # the fleet's file only: gitolite-admin's rules stay the admin's, in gitolite.conf
        "    RW+ = admin",
        "    RW+ refs/reports/robot1$ = robot1",
        "    RW+ refs/reports/robot2$ = robot2",
    ]


def test_a_robot_name_is_matched_literally_not_as_a_pattern():
    text = gitolite.conf("fleet", ["r.1"])
    rule = next(line for line in text.splitlines() if "refs/reports/" in line)
    refex = rule.split()[1]
    assert re.match(refex, "refs/reports/r.1")
    assert not re.match(refex, "refs/reports/rx1")
    assert not re.match(refex, "refs/reports/r.10")


def test_no_robots_no_robot_rules():
    text = gitolite.conf("fleet", [])
    assert "@robotfleet" not in text and "refs/reports" not in text
    assert "repo fleet\n    config receive.maxInputSize = 1g\n    RW+ = admin\n" in text


@pytest.mark.parametrize("name", ["", "-x", "a/b", "robot 1", "a@enroll", "a\nb", 7])
def test_names_gitolite_cannot_take_are_refused(name):
    with pytest.raises(gitolite.GitoliteError, match="cannot be a gitolite user"):
        gitolite.conf("fleet", [name])


def blocks(text: str) -> dict[str, list[str]]:
    """repo -> its rule lines (not its git config lines), from gitolite.conf."""
    found: dict[str, list[str]] = {}
    for line in text.splitlines():
        if line.startswith("repo "):
            current = found.setdefault(line.split()[1], [])
        elif line.startswith("    ") and not line.startswith("    config "):
            current.append(line.strip())
    return found


def test_with_shards_each_robot_writes_its_own_ref_in_its_own_shard_only():
    from robotfleet.pull.protocol import report_shards

    robots = [f"robot{i}" for i in range(1, 21)]
    rules = blocks(gitolite.conf("fleet", robots, shards=4))
    assert sorted(rules) == [
        "fleet",
        "fleet-reports-0",
        "fleet-reports-1",
        "fleet-reports-2",
        "fleet-reports-3",
    ]
    for robot in robots:
        own = f"RW+ refs/reports/{robot}$ = {robot}"
        where = sorted(repo for repo, lines in rules.items() if own in lines)
        # its shard, and the fleet repository where it reported before it moved
        assert where == ["fleet", f"fleet-reports-{report_shards.shard_of(robot, 4)}"], robot
    spread = report_shards.spread(robots, 4)
    for shard in range(4):
        lines = rules[f"fleet-reports-{shard}"]
        assert lines[:2] == ["RW+ = admin", "R = @robotfleet-fleet"], shard  # every robot reads every shard
        # and nothing else is written there but the shard's robots' own report refs
        assert lines[2:] == [f"RW+ refs/reports/{robot}$ = {robot}" for robot in spread[shard]], shard


def test_with_shards_a_shared_key_writes_its_names_in_every_shard_but_a_registered_robot_s():
    from robotfleet.pull.protocol import report_shards

    shared = gitolite.shared_user("machine-id", "robot-")
    enrolled = "robot-0aa0aa0aa0aa"
    rules = blocks(gitolite.conf("fleet", [shared, enrolled, "robot1"], shards=4))
    own = report_shards.shard_repo("fleet", report_shards.shard_of(enrolled, 4))
    deny = f"- refs/reports/{re.escape(enrolled)}$ = {shared}"
    for repo in ("fleet", *(report_shards.shard_repo("fleet", s) for s in range(4))):
        assert f"RW+ refs/reports/{gitolite.shared_refex(shared)}$ = {shared}" in rules[repo]
        assert (deny in rules[repo]) == (repo in ("fleet", own)), repo
        if deny in rules[repo]:  # the deny comes before the shared key's write
            assert rules[repo].index(deny) < rules[repo].index(
                f"RW+ refs/reports/{gitolite.shared_refex(shared)}$ = {shared}"
            )


def test_no_shards_is_the_one_repository_as_before():
    assert gitolite.conf("fleet", ["robot1"], shards=0) == gitolite.conf("fleet", ["robot1"])
    assert "reports-" not in gitolite.conf("fleet", ["robot1"])


def test_key_files_of_own_and_enrollment_keys():
    assert gitolite.key_file("robot1") == "keydir/robot1.pub"
    assert gitolite.key_file("robot1", enrollment=True) == "keydir/robot1@enroll.pub"


def test_robots_are_read_back_from_the_fleet_s_own_key_directory(tmp_path):
    from robotfleet.pull.operator import gitolite_admin

    layout = gitolite_admin.Layout(tmp_path, "fleet")
    layout.keys.mkdir(parents=True)
    for name in ("robot1.pub", "robot1@enroll.pub", "robot2@enroll.pub", "admin.pub", "notes.txt"):
        (layout.keys / name).write_text(KEY)
    (tmp_path / "keydir" / "alice.pub").write_text(KEY)  # a colleague's key: never a robot
    assert layout.robots(("admin",)) == {"robot1", "robot2"}


def test_a_public_key_is_one_line_without_its_comment():
    assert gitolite.check_key(f"\n{KEY} root@robot1\n", "k") == KEY
    for bad in ("", f"{KEY}\n{KEY}", "-----BEGIN OPENSSH PRIVATE KEY-----", "ssh-ed25519 AAA$$"):
        with pytest.raises(gitolite.GitoliteError, match="k: not one OpenSSH public key line"):
            gitolite.check_key(bad, "k")


def test_admin_uses_strict_host_keys_and_only_its_key():
    env = gitolite.Admin("ssh://gitolite3@h:2222", "/k/id", "/k/known").env()
    ssh = env["GIT_SSH_COMMAND"]
    for option in (
        "-i /k/id",
        "IdentitiesOnly=yes",
        "StrictHostKeyChecking=yes",
        "UserKnownHostsFile=/k/known",
        "BatchMode=yes",
    ):
        assert option in ssh


def test_lab_git_server_known_hosts_names_it_both_ways():
    from tests.lab import gitserver

    lines = gitserver.known_hosts_lines(["[127.0.0.1]:24001", "e2e-git"], [KEY + " root@git"])
    assert lines == [f"[127.0.0.1]:24001,e2e-git {KEY}"]


def test_lab_state_may_name_a_git_server(tmp_path):
    from tests.lab import state
    from tests.unit.samples import lab_state as sample

    lab = dict(sample(), git={"container": "t-git", "port": 24001})
    state.save(lab, root=tmp_path)
    assert state.load("t", root=tmp_path)["git"]["port"] == 24001
