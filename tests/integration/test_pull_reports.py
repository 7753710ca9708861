"""Pull robots' reports (robotfleet/pull/protocol/reports.py): the format, the
operator's reading of them as untrusted input, staleness, status rows
(robotfleet/commands/pull/status.py) and the rollout's reading of them."""

from __future__ import annotations

import datetime
import json
import os
import subprocess
from types import SimpleNamespace

import pytest

from robotfleet.commands.pull import rollout as pullrollout
from robotfleet.commands.pull import status as pullstatus
from robotfleet.pull.protocol import catfile, report_store, reports, waves
from robotfleet.pull.robot import transport
from tests.integration import craftedgit

UTC = datetime.timezone.utc
NOW = datetime.datetime(2026, 11, 25, 10, 0, tzinfo=UTC)
KEY = "ssh-ed25519 AAAAC3NzaC1lZDI1NTE5AAAAIGbigA6mqsYKDD3V4SGhrWodxIaju5HYfXtBYAQEvqW0"
CONFIG = SimpleNamespace(interval=60, jitter=5, stale_after=3, heartbeat=0)


def made(result="applied", robot="robot1", when=NOW, **more) -> dict:
    return reports.build(
        robot,
        when,
        result,
        seen={"version": 7, "release": "r7", "commit": "a" * 40},
        applied={"version": 7, "release": "r7", "commit": "a" * 40, "time": "2026-11-25T09:59:00Z"},
        attempted={"version": 7, "result": result, "tries": 1},
        host_keys=[KEY],
        key=KEY,
        config=CONFIG,
        status={"release": "20261125T0959Z-1", "health": "healthy"},
        **more,
    )


def test_a_report_reads_back_as_written():
    report = made(reason="release 7 applied", check={"sent": 10, "received": 20, "seconds": 0.5, "cpu": 0.3})
    found = reports.parse(reports.to_bytes(report), "robot1")
    assert found["result"] == "applied" and found["seen"]["version"] == 7
    assert found["status"] == {"release": "20261125T0959Z-1", "health": "healthy"}
    assert found["check"] == {"sent": 10, "received": 20, "seconds": 0.5, "cpu": 0.3}
    assert found["host_keys"] == [KEY] and found["interval"] == 60


@pytest.mark.parametrize(
    "change, line",
    [
        (lambda r: r.update(robot="robot2"), "report of robot1: names another robot (robot2)"),
        (lambda r: r.update(result="pwned"), "report of robot1: unknown result pwned"),
        (lambda r: r.update(format=2), "report of robot1: not a format 1 report"),
        (lambda r: r.update(time="yesterday"), "report of robot1: time is not a UTC time"),
        (
            lambda r: r.update(host_keys=["ssh-ed25519 AAAA; rm -rf /"]),
            "report of robot1: host_keys: expected public key lines",
        ),
        (lambda r: r.update(key="not a key"), "report of robot1: key: expected a public key line"),
        (
            lambda r: r.update(enrollment={"key": KEY, "signature": "-----BEGIN SSH SIGNATURE-----\n$(x)"}),
            "report of robot1: enrollment: expected {key, signature}",
        ),
        (lambda r: r["seen"].update(version=-1), "seen.version: expected a whole number"),
    ],
)
def test_a_report_a_robot_wrote_wrong_is_one_line(change, line):
    report = made()
    change(report)
    with pytest.raises(reports.ReportError, match=line.replace("(", r"\(").replace(")", r"\)")):
        reports.parse(reports.to_bytes(report), "robot1")


def test_text_from_a_robot_is_shown_not_obeyed():
    report = made(result="failed", reason="bad\x1b[2Jthing\nnext line")
    report["status"] = {"health": "ok\x07", "nested": {"x\x1b": ["\u202e"]}}
    found = reports.parse(reports.to_bytes(report), "robot1")
    assert found["reason"] == "bad\\x1b[2Jthing\\x0anext line"
    assert "\x1b" not in json.dumps(found) and "\x07" not in json.dumps(found)
    with pytest.raises(reports.ReportError, match="not JSON"):
        reports.parse(b"\xff{", "robot1")
    with pytest.raises(reports.ReportError, match="larger than"):
        reports.parse(b" " * (reports.MAX_BYTES + 1), "robot1")


def test_a_report_nested_too_deep_is_one_line_and_brackets_in_text_do_not_count():
    for data in (b"[" * 200000, b"{" * 200000, b'{"a":' * 65 + b"1" + b"}" * 65, b"[" * 65 + b"]" * 65):
        with pytest.raises(reports.ReportError, match=f"^report of robot1: nested deeper than {reports.MAX_DEPTH} "):
            reports.parse(data, "robot1")
    with pytest.raises(reports.ReportError, match="not a format 1 report"):
        reports.parse(b"[" * 64 + b"]" * 64, "robot1")
    with pytest.raises(reports.ReportError, match="not JSON"):
        reports.parse(b'"' + b"[" * 100, "robot1")  # an open string: no depth, and not JSON either
    report = made(reason="[{" * 200 + '\\"' + "[" * 200 + '"' + "{" * 200)
    assert reports.parse(reports.to_bytes(report), "robot1")["reason"].startswith("[{[{")
    assert not reports.too_deep(b'["\\"[[[[["]', 3)  # an escaped quote does not end the string
    assert reports.too_deep(b'["\\\\"[[[]]]]', 3)  # an escaped backslash does not escape the quote after it


def test_stale_after_so_many_heartbeats_each_with_an_interval_and_its_jitter():
    report = made()
    assert not reports.stale(report, NOW + datetime.timedelta(seconds=195), 60, 5, 3)
    assert reports.stale(report, NOW + datetime.timedelta(seconds=196), 60, 5, 3)
    assert not reports.stale(report, NOW + datetime.timedelta(seconds=1330), 60, 5, 2, heartbeat=600)
    assert reports.stale(report, NOW + datetime.timedelta(seconds=1331), 60, 5, 2, heartbeat=600)


def test_a_failure_counts_for_the_version_it_was_for():
    assert reports.failed_for(made("rolled-back"), 7) and not reports.failed_for(made("rolled-back"), 8)
    assert not reports.failed_for(made("applied"), 7)


def test_the_substance_leaves_out_when_and_what_it_cost():
    one, two = made(check={"cpu": 1}), made(when=NOW + datetime.timedelta(minutes=1), check={"cpu": 2})
    assert reports.substance(one) == reports.substance(two)
    assert reports.substance(one) != reports.substance(made("waiting"))


def test_status_rows_from_reports():
    data = {"pull_interval": 60, "pull_jitter": 5, "pull_stale_after": 3, "pull_heartbeat": 600}
    row = pullstatus.row("robot1", reports.parse(reports.to_bytes(made()), "robot1"), data, NOW, "url")
    assert (row["reachable"], row["pull"], row["health"], row["reported"]) == (
        "pull",
        "applied 7",
        "healthy",
        "2026-11-25T10:00:00Z",
    )
    assert "error" not in row
    late = pullstatus.row(
        "robot1", reports.parse(reports.to_bytes(made()), "robot1"), data, NOW + datetime.timedelta(hours=1), "url"
    )
    assert late["reachable"] is False and late["reported"].endswith(" STALE") and "stale report" in late["error"]
    refused = made("refused", refusal="tampered", reason="timestamp.json: changed after it was signed")
    row = pullstatus.row("robot1", reports.parse(reports.to_bytes(refused), "robot1"), data, NOW, "url")
    assert row["pull"] == "refused 7 (tampered)" and row["error"].startswith("refused: timestamp.json")
    stopped = made(
        "stopped", reason="wave 1 stopped by the failure budget: 1 robot(s) of the earlier waves failed (budget 0)"
    )
    row = pullstatus.row("robot1", reports.parse(reports.to_bytes(stopped), "robot1"), data, NOW, "url")
    assert row["pull"] == "stopped 7 (failure budget)" and "error" not in row  # not an operator's halt, not a fault
    missing = pullstatus.row("robot2", None, data, NOW, "ssh://git/fleet")
    assert missing["reachable"] is False and "no report in refs/reports/robot2 of ssh://git/fleet" in missing["error"]


def test_the_operator_reads_every_report_with_one_fetch(tmp_path):
    bare = tmp_path / "fleet.git"
    subprocess.run(["git", "init", "-q", "--bare", str(bare)], check=True)
    for name, body in (("robot1", reports.to_bytes(made())), ("robot2", b"garbage")):
        transport.Remote(f"file://{bare}", tmp_path / name, str(tmp_path / "etc"), timeout=30).push_report(name, body)
    cache = tmp_path / "cache"
    report_store.fetch_all(f"file://{bare}", cache)
    found = report_store.read_all(cache)
    assert found["robot1"]["result"] == "applied"
    assert found["robot2"] == {"robot": "robot2", "error": "report of robot2: not JSON"}


def test_a_pull_rollout_s_waves_and_what_it_counts():
    args = SimpleNamespace(
        canary=waves.parse_count("1", "c"),
        batch=waves.parse_count("25%", "b"),
        pause=60,
        max_failed=waves.parse_count("0", "m"),
    )
    assert [str(w) for w in pullrollout.plan_of(args).waves] == ["25%", "50%", "75%", "100%"]
    args.batch = waves.parse_count("30%", "b")
    assert [str(w) for w in pullrollout.plan_of(args).waves] == ["30%", "60%", "90%", "100%"]
    args.batch = waves.parse_count("2", "b")
    assert [str(w) for w in pullrollout.plan_of(args).waves] == ["100%"]
    args.fleet, args.remote, args.keys, args.publish_option = "robots.yaml", None, None, []
    assert pullrollout.publish_argv(args, pullrollout.plan_of(args))[-2:] == ["--pause", "60"]
    args.pause = None  # no --pause: publish's own default (the robots' longest check period) decides
    assert "--pause" not in pullrollout.publish_argv(args, pullrollout.plan_of(args))
    assert pullrollout.apart(args, pullrollout.plan_of(args)).startswith("as far apart as the robots' longest")
    # followed until an hour past the last wave's opening, unless --timeout says: a canary and 4 waves of 8
    args.pause, args.batch = 60, waves.parse_count("25%", "b")
    record = SimpleNamespace(robots=[f"robot{i}" for i in range(8)], version=3, rollout=pullrollout.plan_of(args))
    assert len(waves.waves(record.robots, 3, record.rollout)) == 5
    assert pullrollout.following(None, record) == 4 * 60 + 3600
    assert pullrollout.following(120, record) == 120
    applied = reports.parse(reports.to_bytes(made()), "robot1")
    assert pullrollout.outcome(applied, 7) == "done" and pullrollout.outcome(applied, 8) is None
    assert pullrollout.outcome(reports.parse(reports.to_bytes(made("rolled-back")), "robot1"), 7) == "failed"
    assert pullrollout.outcome(None, 7) is None


def test_status_reads_pull_robots_from_their_reports_and_never_connects(tmp_path):
    from robotfleet.commands import status, status_collect

    bare = tmp_path / "fleet.git"
    subprocess.run(["git", "init", "-q", "--bare", str(bare)], check=True)
    fresh = made(when=datetime.datetime.now(UTC).replace(microsecond=0))
    transport.Remote(f"file://{bare}", tmp_path / "r1", str(tmp_path / "etc"), timeout=30).push_report(
        "robot1", reports.to_bytes(fresh)
    )
    inventory = tmp_path / "inv.py"
    # Addresses nothing listens on: a connection attempt would be an error row, not a report's.
    inventory.write_text(
        'robots = [("robot1", {"pull_enabled": True, "ssh_hostname": "192.0.2.1",\n'
        '                      "pull_interval": 60}),\n'
        '          ("robot2", {"pull_enabled": True, "ssh_hostname": "192.0.2.2"})]\n'
    )
    rows = {r["host"]: r for r in status_collect.collect(str(inventory), [], remote=f"file://{bare}")}
    assert rows["robot1"]["reachable"] == "pull" and rows["robot1"]["pull"] == "applied 7"
    assert rows["robot1"]["health"] == "healthy" and "error" not in rows["robot1"]
    assert rows["robot2"]["reachable"] is False and "no report in refs/reports/robot2" in rows["robot2"]["error"]
    assert status.exit_code(list(rows.values())) == 3


# -- a hostile robot's report: crafted git objects, read through the real reading path ------------------------


@pytest.fixture
def fleet(tmp_path):
    """A bare fleet remote with honest reports (robot2 failed, robot3 applied), and a robot's own repository."""
    bare = tmp_path / "fleet.git"
    subprocess.run(["git", "init", "-q", "--bare", str(bare)], check=True)
    for name, result in (("robot2", "failed"), ("robot3", "applied")):
        transport.Remote(f"file://{bare}", tmp_path / name, str(tmp_path / "etc"), timeout=30).push_report(
            name, reports.to_bytes(made(result, robot=name))
        )
    return bare, craftedgit.workspace(tmp_path / "hostile")


def test_a_report_that_is_a_tree_is_its_robot_s_line_and_speaks_for_no_other(fleet, tmp_path):
    bare, work = fleet
    tree = craftedgit.forging_tree(work, reports.to_bytes(made("applied", robot="robot2")))  # robot2 failed
    craftedgit.push_report_entry(bare, work, "robot1", f"040000 tree {tree}\treport.json")
    cache = tmp_path / "cache"
    report_store.fetch_all(f"file://{bare}", cache)
    found = report_store.read_all(cache)
    assert found["robot1"] == {"robot": "robot1", "error": "report of robot1: report.json: a tree, not a blob"}
    assert found["robot2"]["result"] == "failed" and found["robot3"]["result"] == "applied"
    # a robot of a later wave reads the same way: robot2's failure counts
    reader = transport.Remote(f"file://{bare}", tmp_path / "reader", str(tmp_path / "etc"), timeout=30)
    earlier = reader.fetch_reports(["robot1", "robot2", "robot3"])
    assert "error" in earlier["robot1"] and reports.failed_for(earlier["robot2"], 7)
    assert earlier["robot3"]["result"] == "applied"


def test_each_malformed_report_is_its_robot_s_line_in_status(fleet, tmp_path):
    from robotfleet.commands import status_collect

    bare, work = fleet
    deep = craftedgit.blob(work, b"[" * 200000)  # nested deeper than json.loads goes
    craftedgit.push_report_entry(bare, work, "robot4", f"100644 blob {deep}\treport.json")
    large = craftedgit.blob(work, b" " * (3 * 1024 * 1024))
    craftedgit.push_report_entry(bare, work, "robot5", f"100644 blob {large}\treport.json")
    craftedgit.push_report_entry(bare, work, "robot6", f"100644 blob {large}\tnot-a-report.json")  # no report.json
    tree = craftedgit.git(work, "mktree", stdin=f"100644 blob {large}\tx\n".encode())
    craftedgit.push_report_entry(bare, work, "robot7", f"040000 tree {tree}\treport.json")  # a well-formed tree
    inventory = tmp_path / "inv.py"
    inventory.write_text(
        "robots = ["
        + ", ".join(f'("robot{n}", {{"pull_enabled": True, "ssh_hostname": "192.0.2.{n}"}})' for n in range(2, 8))
        + "]\n"
    )
    rows = {r["host"]: r for r in status_collect.collect(str(inventory), [], remote=f"file://{bare}")}
    assert rows["robot2"]["pull"] == "failed 7" and rows["robot3"]["pull"] == "applied 7"
    unreadable = {name: row["error"] for name, row in rows.items() if row["pull"] == "unreadable"}
    assert unreadable == {
        "robot4": f"report of robot4: nested deeper than {reports.MAX_DEPTH} levels",
        "robot5": f"report of robot5: report.json: larger than {reports.MAX_BYTES} bytes ({3 * 1024 * 1024})",
        "robot6": "report of robot6: report.json: missing",
        "robot7": "report of robot7: report.json: a tree, not a blob",
    }


def test_a_report_larger_than_allowed_is_never_read_into_memory(fleet, tmp_path):
    import tracemalloc

    bare, work = fleet
    size = 8 * 1024 * 1024
    huge = craftedgit.blob(work, b"x" * size)
    craftedgit.push_report_entry(bare, work, "robot1", f"100644 blob {huge}\treport.json")
    cache = tmp_path / "cache"
    report_store.fetch_all(f"file://{bare}", cache)
    tracemalloc.start()
    try:
        found = report_store.read_all(cache)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert found["robot1"]["error"] == f"report of robot1: report.json: larger than {reports.MAX_BYTES} bytes ({size})"
    assert found["robot2"]["result"] == "failed"
    assert peak < 4 * reports.MAX_BYTES, peak
    with pytest.raises(catfile.CatFileError, match=r"^git cat-file: no answer within 0\.05 s$"):
        catfile.blobs(cache, [huge] * 50, reports.MAX_BYTES, timeout=0.05)  # bounded in time too


def test_the_lab_s_git_server_refuses_a_push_holding_a_malformed_object(fleet):
    from tests.lab import gitserver

    bare, work = fleet
    blob = bytes.fromhex(craftedgit.blob(work, b"x"))
    # git walks it (so it packs and pushes it), fsck does not: a ".git" entry, as in CVE-2014-9390's trees
    raw = b"100644 .git\0%s100644 report.json\0%s" % (blob, blob)
    tree = craftedgit.git(work, "hash-object", "-t", "tree", "--literally", "-w", "--stdin", stdin=raw)
    craftedgit.push_report_entry(bare, work, "robot1", f"040000 tree {tree}\tcrafted")  # a server that checks nothing
    for key, value in gitserver.GIT_CONFIG.items():
        craftedgit.git(bare, "config", key, value)
    with pytest.raises(subprocess.CalledProcessError) as refused:
        craftedgit.push_report_entry(bare, work, "robot4", f"040000 tree {tree}\tcrafted")
    assert b"hasDotgit" in refused.value.stderr, refused.value.stderr
    assert "refs/reports/robot4" not in craftedgit.git(bare, "for-each-ref")


def test_where_the_server_allows_a_filter_the_operator_never_downloads_a_report_over_the_cap(fleet, tmp_path):
    bare, work = fleet
    subprocess.run(["git", "-C", str(bare), "config", "uploadpack.allowFilter", "true"], check=True)
    huge = craftedgit.blob(work, os.urandom(4 * 1024 * 1024))  # does not compress: the download would show
    craftedgit.push_report_entry(bare, work, "robot1", f"100644 blob {huge}\treport.json")
    cache = tmp_path / "cache"

    def stored() -> int:
        return sum(p.stat().st_size for p in (cache / "objects").rglob("*") if p.is_file())

    for _ in range(2):  # a second read neither fetches the blob after all (no lazy fetch) nor fails
        found = report_store.fetch_every(f"file://{bare}", 0, cache)
        assert found["robot1"] == {"robot": "robot1", "error": "report of robot1: report.json: missing"}
        assert found["robot2"]["result"] == "failed" and found["robot3"]["result"] == "applied"
        assert stored() < 1024 * 1024, stored()
