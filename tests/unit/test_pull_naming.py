"""How a robot from an image shared by many robots names itself
(robotfleet/pull/protocol/naming.py), the agent's configuration that says so, and
what the git server lets the image's one enrollment key write."""

import re

import pytest

from robotfleet.pull.operator import gitolite
from robotfleet.pull.protocol import agent_files, naming

MACHINE_ID = "3f2a9c0d1e2b4a5f8c7d6e5f4a3b2c1d\n"


def test_a_machine_id_names_the_robot_by_its_first_12_hex_digits():
    assert naming.derive("machine-id", "robot-", MACHINE_ID) == "robot-3f2a9c0d1e2b"
    assert naming.derive("machine-id", "lab.", MACHINE_ID) == "lab.3f2a9c0d1e2b"
    assert re.fullmatch(naming.PATTERNS["machine-id"], "3f2a9c0d1e2b")


@pytest.mark.parametrize("raw", ["", "uninitialized\n", "3F2A9C0D1E2B4A5F8C7D6E5F4A3B2C1D", "3f2a9c0d"])
def test_a_machine_id_that_is_not_one_is_refused(raw):
    with pytest.raises(naming.NamingError, match=r"^/etc/machine-id: expected 32 lowercase hex digits"):
        naming.derive("machine-id", "robot-", raw)


def test_a_board_serial_is_lowercased_and_made_a_name():
    assert naming.derive("dmi-serial", "robot-", "PF3K 9Z/01\n") == "robot-pf3k-9z-01"
    assert re.fullmatch(naming.PATTERNS["dmi-serial"], "pf3k-9z-01")


@pytest.mark.parametrize("raw", ["To Be Filled By O.E.M.", "Default string\n", "0123456789", "000000", " ", "None"])
def test_a_placeholder_serial_is_refused_since_every_robot_would_share_it(raw):
    with pytest.raises(naming.NamingError, match="is a placeholder, not this board's serial"):
        naming.derive("dmi-serial", "robot-", raw)


@pytest.mark.parametrize(
    "rule, prefix, line",
    [
        ("hostname", "robot-", "name rule 'hostname': expected one of machine-id, dmi-serial"),
        ("machine-id", "-x", "name prefix '-x': expected letters"),
        ("machine-id", "a/b", "name prefix 'a/b': expected letters"),
    ],
)
def test_bad_rules_and_prefixes_are_one_line(rule, prefix, line):
    with pytest.raises(naming.NamingError, match=re.escape(line)):
        naming.derive(rule, prefix, MACHINE_ID)


def test_the_agent_s_configuration_carries_a_name_or_the_rule_never_both():
    config = agent_files.Config(robot="", remote="ssh://g@git/fleet", name_rule="machine-id", name_prefix="robot-")
    read = agent_files.read_config(config.to_json())
    assert (read.robot, read.name_rule, read.name_prefix) == ("", "machine-id", "robot-")
    assert agent_files.named(read, read=lambda rule: MACHINE_ID).robot == "robot-3f2a9c0d1e2b"
    with pytest.raises(agent_files.ConfigError, match=r"^robot name: /etc/machine-id: expected 32"):
        agent_files.named(read, read=lambda rule: "")
    both = config.to_json().replace('"robot": ""', '"robot": "robot1"')
    with pytest.raises(agent_files.ConfigError, match="robot and name_rule: give one"):
        agent_files.read_config(both)
    named = agent_files.Config(robot="robot1", remote="ssh://g@git/fleet")
    assert "name_rule" not in named.to_json() and agent_files.named(named) == named  # unchanged for a named robot
    with pytest.raises(agent_files.ConfigError, match=r"robot: required, a string \(or name_rule\)"):
        agent_files.read_config(named.to_json().replace('"robot": "robot1"', '"robot": ""'))


def test_a_shared_enrollment_key_writes_only_reports_of_names_its_rule_makes_and_not_enrolled_ones():
    user = gitolite.shared_user("machine-id", "robot-")
    assert user == "enroll+machine-id+robot-"
    text = gitolite.conf("fleet", ["robot1", "robot-0123456789ab", user])
    assert "@robotfleet-fleet = enroll+machine-id+robot- robot-0123456789ab robot1" in text  # it reads the releases
    rules = [line.split() for line in text.splitlines() if line.strip().endswith(f"= {user}")]
    # gitolite takes the first rule matching a ref: the enrolled robot's deny comes first
    assert [r[0] for r in rules] == ["-", "RW+"]

    def may_write(ref: str) -> bool:
        for perm, refex, _, _ in rules:
            if re.match(refex, ref):
                return perm != "-"
        return False

    assert may_write("refs/reports/robot-3f2a9c0d1e2b")
    assert not may_write("refs/reports/robot-0123456789ab")  # an enrolled robot's: a leaked image cannot speak for it
    assert not may_write("refs/reports/robot1")
    assert not may_write("refs/reports/robot-3f2a9c0d1e2bX") and not may_write("refs/heads/robotfleet/releases")
    with pytest.raises(naming.NamingError):
        gitolite.shared_user("hostname", "robot-")
