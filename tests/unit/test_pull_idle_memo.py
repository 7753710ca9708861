"""The idle check's small readers (robotfleet/pull/robot/idle.py,
trust_fingerprint.py) agree with the full wake's: the same caps, the same
trust.json, the same times.  The check itself, in its process against a
real server: tests/integration/test_pull_idle_memo.py."""

from __future__ import annotations

import datetime

from robotfleet.pull.protocol import record as records
from robotfleet.pull.robot import idle, trust_fingerprint, trust_state


def test_the_fingerprint_reads_a_record_up_to_the_record_s_own_cap():
    assert trust_fingerprint.RECORD_MAX == records.MAX_BYTES


def test_the_trusted_time_the_idle_check_writes_is_what_trust_state_writes_and_reads(tmp_path):
    moment = datetime.datetime(2026, 11, 27, 23, 31, 44, tzinfo=datetime.timezone.utc)
    trust_state.write_state(tmp_path, trust_state.State(moment, 3, "r-3"))
    written = (tmp_path / "trust.json").read_bytes()
    assert trust_fingerprint.trust_bytes(records.utc(moment), 3, "r-3") == written
    assert trust_state.read_state(tmp_path) == trust_state.State(moment, 3, "r-3")


def test_a_time_is_one_as_records_write_it_and_nothing_else():
    assert idle._is_time(records.utc(datetime.datetime(2026, 1, 2, 3, 4, 5, tzinfo=datetime.timezone.utc)))
    for bad in (
        None,
        5,
        "",
        "2026-11-27T23:31:44",
        "2026-11-27 23:31:44Z",
        "2026-11-27T23:31:4xZ",
        "２026-11-27T23:31:44Z",
    ):
        assert not idle._is_time(bad), bad


def test_only_the_unit_s_own_arguments_are_taken_by_the_idle_check():
    assert idle._config_path(["--config", "/etc/robot-pull/agent.json"]) == "/etc/robot-pull/agent.json"
    assert idle._config_path(["--config=/x.json"]) == "/x.json"
    for other in ([], ["--help"], ["--config"], ["--config", "a", "--other"]):
        assert idle._config_path(other) is None, other


def test_the_remotes_the_memo_covers_over_ssh_are_those_git_reaches_with_ssh():
    from robotfleet.pull.robot import remote_git

    for ssh in ("ssh://gitolite3@git.lan/fleet", "git+ssh://git.lan:2222/fleet", "gitolite3@git.lan:fleet", "h:f"):
        assert remote_git.is_ssh(ssh), ssh
    for other in ("https://git.lan/fleet", "file:///srv/fleet.git", "/srv/fleet.git", "./a:b", "git://git.lan/f"):
        assert not remote_git.is_ssh(other), other
