"""One wording for one cause (issue 39 item 7): a host that cannot be reached
is worded by robotfleet/reasons.py whichever command met it (a deploy and
status through paramiko's client, enroll through its own socket), and the
status table shows the reason in a word or two."""

from __future__ import annotations

import errno

import pytest
from paramiko.ssh_exception import NoValidConnectionsError

from robotfleet import reasons, status_parts
from robotfleet.commands import status


def paramiko_s(code: int, text: str) -> NoValidConnectionsError:
    """What paramiko's SSHClient.connect raises for a socket error (status and deploys meet this)."""
    return NoValidConnectionsError({("192.0.2.200", 22): OSError(code, text)})


@pytest.mark.parametrize(
    "code, text, said",
    [
        (errno.EHOSTUNREACH, "No route to host", "no route to 192.0.2.200:22 (No route to host)"),
        (errno.ENETUNREACH, "Network is unreachable", "no route to 192.0.2.200:22 (Network is unreachable)"),
        (
            errno.ECONNREFUSED,
            "Connection refused",
            "connection refused by 192.0.2.200:22 (no SSH server listens on port 22)",
        ),
        (
            errno.ETIMEDOUT,
            "Connection timed out",
            "timed out after 10 s connecting to 192.0.2.200:22 (no answer: powered off, wrong address or a firewall)",
        ),
    ],
)
def test_the_same_cause_is_worded_the_same_through_paramiko_and_a_plain_socket(code, text, said):
    plain = OSError(code, text)  # what enroll's socket.create_connection raises
    assert reasons.network_reason(plain, "192.0.2.200", 22, 10) == reasons.network_reason(
        paramiko_s(code, text), "192.0.2.200", 22, 10
    )
    assert reasons.network_reason(plain, "192.0.2.200", 22, 10)[0] == said
    assert "Unable to connect" not in reasons.network_reason(paramiko_s(code, text), "192.0.2.200", 22, 10)[0]


def test_one_refused_address_of_several_does_not_hide_the_others_reason():
    both = NoValidConnectionsError(
        {
            ("::1", 22, 0, 0): OSError(errno.ECONNREFUSED, "Connection refused"),
            ("192.0.2.200", 22): OSError(errno.EHOSTUNREACH, "No route to host"),
        }
    )
    assert reasons.network_reason(both, "robot1", 22, 10)[0] == "no route to robot1:22 (No route to host)"


@pytest.mark.parametrize(
    "error, word",
    [
        ("connection refused by 10.0.0.1:22 (no SSH server listens on port 22)", "refused"),
        ("timed out after 10 s connecting to 10.0.0.1:22 (no answer: ...)", "timed out"),
        ("no route to 10.0.0.1:22 (No route to host)", "no route"),
        ("host key CHANGED: ~/.ssh/known_hosts has SHA256:a for ...", "host key"),
        ("unknown host key: [10.0.0.1]:22 is not in known_hosts", "host key"),
        ("authentication failed for user ops with key k", "login refused"),
        ("not an SSH server: 10.0.0.1:22 answered, but not with an SSH greeting", "not SSH"),
        ("cannot resolve robot9 (Name or service not known)", "unknown name"),
        ("status failed: boom", "error"),
    ],
)
def test_the_reachable_column_carries_the_reason_in_a_word_or_two(error, word):
    row = status_parts.row("robot2", (), None, error)
    text = status.table([row], status_parts.FIRST).splitlines()
    assert text[1].split("  ")[0:2] == ["robot2", f"no: {word}"], text
    assert status.reachable(row) == f"no: {word}"


def test_a_pull_robot_without_a_fresh_report_says_so_in_the_column():
    assert (
        status.reachable(
            {
                "host": "r",
                "reachable": False,
                "via": "report",
                "pull": "no report",
                "error": "no report in refs/reports/r of URL",
            }
        )
        == "pull: no report yet"
    )
    assert (
        status.reachable(
            {
                "host": "r",
                "reachable": False,
                "via": "report",
                "pull": "applied 3",
                "error": "stale report: last at 2026-11-27T10:00:00Z, ...",
            }
        )
        == "pull: stale report"
    )


def test_every_reason_the_connector_words_has_its_short_word():
    for start in reasons.REASONS:
        assert reasons.short_reason(start + " ..."), start
