"""The idle probe's reading of what a remote says (robotfleet/pull/robot/probe.py):
git's listings, pkt-lines, and which validators of a static copy stand."""

from __future__ import annotations

from pathlib import Path

from robotfleet.pull.robot import probe

A, B = "a" * 40, "b" * 64
REF = "refs/heads/robotfleet/releases"


def test_the_branch_s_commit_is_read_from_each_listing_and_only_as_an_object_id():
    listing = f"{B}\trefs/heads/robotfleet/releases-old\n{A}\t{REF}\n".encode()
    assert probe.commit_of(listing, REF) == A  # info/refs, ls-remote
    assert probe.commit_of(f"{B} {REF}\n".encode(), REF) == B  # ls-refs (sha256 repositories too)
    assert probe.commit_of(f"{A}\trefs/reports/robot1\n".encode(), REF) is None
    assert probe.commit_of(f"not-an-id\t{REF}\n".encode(), REF) is None
    assert probe.commit_of(f"{A.upper()}\t{REF}\n".encode(), REF) is None


def test_pkt_lines_up_to_the_flush_or_none():
    request = probe.ls_refs_request(REF)
    assert request == (b"0014command=ls-refs\n0001" + f"{len(REF) + 16:04x}ref-prefix {REF}\n".encode() + b"0000")
    answer = probe.pkt(f"{A} {REF}\n") + b"0000"
    assert probe.pkt_lines(answer) == f"{A} {REF}\n".encode()
    for broken in (answer[:-4], b"zzzz", b"0003", b"00ffshort"):
        assert probe.pkt_lines(broken) is None


def test_a_static_copy_s_validators_stand_only_a_minute_after_it_was_written():
    date = "Fri, 27 Nov 2026 20:00:00 GMT"
    old = {"etag": '"5f-1"', "last-modified": "Fri, 27 Nov 2026 19:59:00 GMT", "date": date}
    assert probe.validators_of(old) == {"etag": '"5f-1"', "last_modified": "Fri, 27 Nov 2026 19:59:00 GMT"}
    assert probe.validators_of({**old, "last-modified": "Fri, 27 Nov 2026 19:59:30 GMT"}) == {}
    assert probe.validators_of({**old, "date": None}) == {}  # no Date to judge it by
    assert probe.validators_of({"etag": '"x"'}) == {"etag": '"x"'}  # a content hash, not a date
    assert probe.validators_of({}) == {}


def test_a_memo_is_read_only_for_its_remote_and_branch_with_a_commit(tmp_path):
    (tmp_path / ".git").mkdir()
    probe.write_memo(tmp_path, "https://m/fleet.git", "robotfleet/releases", A, "static", {"etag": '"x"'})
    assert probe.read_memo(tmp_path, "https://m/fleet.git", "robotfleet/releases")["commit"] == A
    assert probe.read_memo(tmp_path, "https://other/fleet.git", "robotfleet/releases") is None
    assert probe.read_memo(tmp_path, "https://m/fleet.git", "main") is None
    Path(probe.memo_path(tmp_path)).write_text('{"url": "u", "branch": "b", "commit": "../x"}')
    assert probe.read_memo(tmp_path, "u", "b") is None
    probe.forget(tmp_path)
    assert probe.read_memo(tmp_path, "u", "b") is None
