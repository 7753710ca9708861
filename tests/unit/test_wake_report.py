"""What the agent's report step decides without a host (robotfleet/pull/robot/wake_report.py)."""

from __future__ import annotations

import pytest

from robotfleet.pull.robot.wake_report import same_ssh_server


@pytest.mark.parametrize(
    "one, other, same",
    [
        ("ssh://gitolite3@git.lan/fleet", "ssh://gitolite3@git.lan/fleet", True),
        ("ssh://gitolite3@git.lan/fleet", "ssh://gitolite3@git.lan/fleet-reports-7", True),  # a shard
        ("ssh://gitolite3@git.lan:2222/fleet", "ssh://gitolite3@git.lan/fleet", False),
        ("ssh://gitolite3@git.lan/fleet", "ssh://git@git.lan/fleet", False),
        ("ssh://gitolite3@git.lan/fleet", "ssh://gitolite3@reports.lan/fleet", False),
        ("https://git.lan/fleet.git", "https://git.lan/fleet.git", False),  # no SSH login to count
        ("ssh://gitolite3@[::1/fleet", "ssh://gitolite3@[::1/fleet", False),  # not a URL
        ("gitolite3@git.lan:fleet", "ssh://gitolite3@git.lan/fleet-reports-7", True),  # git's scp-like form
        ("gitolite3@git.lan:fleet", "gitolite3@git.lan:fleet", True),
        ("gitolite3@git.lan:fleet", "git@git.lan:fleet", False),
        ("gitolite3@[2001:db8::1]:fleet", "ssh://gitolite3@[2001:db8::1]/fleet", True),
        ("ssh://gitolite3@git.lan:22/fleet", "ssh://gitolite3@git.lan/fleet", True),  # ssh's own port, said or not
        ("ssh://gitolite3@Git.LAN/fleet", "gitolite3@git.lan:fleet", True),
    ],
)
def test_a_report_is_not_pushed_where_the_same_login_was_just_refused(one, other, same):
    assert same_ssh_server(one, other) is same
