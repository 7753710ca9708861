"""The snapshot's memo: what a probe or a part of the script depends on
alone (files, programs, dpkg's database) keeps its answer on the host while
none of it changed, and is read again as soon as any did."""

from __future__ import annotations

import os
import shlex
import subprocess

import pytest

from robotfleet.host import apt, snapshot_sh
from robotfleet.host import snapshot as hoststate
from tests.integration.dpkg_databases import CASES, admindir, audit_now, stanza


@pytest.fixture
def memo_here(tmp_path, monkeypatch):
    """The memo in a directory of this test, kept for this user."""
    monkeypatch.setattr(snapshot_sh, "MEMO_DIR", str(tmp_path / "memo"))
    monkeypatch.setattr(snapshot_sh, "MEMO_OWNER", os.getuid())
    return tmp_path / "memo"


def snapshot_with_memo(tmp_path, inputs=None, path=None):
    """Run a snapshot whose one probe counts its runs; its answer."""
    key = tmp_path / "key"
    if not key.exists():
        key.write_text("one\n")
    counter = tmp_path / "runs"
    probe = f"echo run >> {shlex.quote(str(counter))}; cat {shlex.quote(str(key))}"
    query = dict(probes={"key": probe, "plain": "echo plain"}, memo={"key": inputs or (str(key), "sh")})
    env = dict(os.environ, PATH=path or os.environ["PATH"])
    out = subprocess.run(
        ["sh", "-c", hoststate.snapshot_script(**query)], capture_output=True, text=True, check=True, env=env
    )
    snap = hoststate.parse(out.stdout.splitlines(), query)
    runs = len(counter.read_text().splitlines()) if counter.exists() else 0
    return snap.probes["key"], snap.probes["plain"], runs


def test_a_memo_probe_is_answered_from_the_memo_while_its_inputs_are_unchanged(tmp_path, memo_here):
    assert snapshot_with_memo(tmp_path) == ("one\n", "plain\n", 1)
    assert snapshot_with_memo(tmp_path) == ("one\n", "plain\n", 1)  # not run again
    assert oct(memo_here.stat().st_mode)[-3:] == "700" and not [p for p in memo_here.iterdir() if ".$" in p.name]
    (tmp_path / "key").write_text("two\n")  # an input changed
    assert snapshot_with_memo(tmp_path) == ("two\n", "plain\n", 2)
    assert snapshot_with_memo(tmp_path) == ("two\n", "plain\n", 2)


def test_a_memo_probe_runs_again_when_its_program_changes(tmp_path, memo_here):
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    tool = bin_dir / "tool"
    tool.write_text("#!/bin/sh\necho v1\n")
    tool.chmod(0o755)
    path = f"{bin_dir}:{os.environ['PATH']}"
    inputs = (str(tmp_path / "key"), "tool")
    assert snapshot_with_memo(tmp_path, inputs, path)[2] == 1
    assert snapshot_with_memo(tmp_path, inputs, path)[2] == 1
    tool.unlink()
    tool.write_text("#!/bin/sh\necho v2\n")  # upgraded: another file
    tool.chmod(0o755)
    assert snapshot_with_memo(tmp_path, inputs, path)[2] == 2


@pytest.mark.parametrize("spoil", ["open to others", "someone else's", "a link", "a stale entry"])
def test_no_memo_is_trusted_but_the_owners_own_up_to_date_one(tmp_path, memo_here, monkeypatch, spoil):
    assert snapshot_with_memo(tmp_path)[2] == 1
    if spoil == "open to others":
        memo_here.chmod(0o777)
    elif spoil == "someone else's":
        monkeypatch.setattr(snapshot_sh, "MEMO_OWNER", os.getuid() + 1)
    elif spoil == "a link":
        real = tmp_path / "elsewhere"
        memo_here.rename(real)
        memo_here.symlink_to(real)
    else:
        for entry in memo_here.iterdir():
            key, value = entry.read_text().splitlines()
            entry.write_text(f"{key}x\n{value}\n")
    assert snapshot_with_memo(tmp_path) == ("one\n", "plain\n", 2)
    assert snapshot_with_memo(tmp_path)[2] == (2 if spoil == "a stale entry" else 3)


def test_a_probe_cut_off_by_the_timeout_is_not_kept(tmp_path, memo_here, monkeypatch):
    monkeypatch.setattr(snapshot_sh, "PROBE_TIMEOUT", 1)
    query = dict(probes={"slow": "sleep 5; echo late"}, memo={"slow": ("/etc/hostname",)})
    for _ in range(2):
        out = subprocess.run(
            ["sh", "-c", hoststate.snapshot_script(**query)], capture_output=True, text=True, check=True, timeout=20
        )
        assert hoststate.parse(out.stdout.splitlines(), query).probes["slow"] == ""
    kept = snapshot_sh.memo_name("slow", "sleep 5; echo late", ("/etc/hostname",))
    assert memo_here.is_dir() and not (memo_here / kept).exists()


def test_dpkg_audit_probe_is_kept_in_the_memo_until_dpkg_s_database_changes(tmp_path, memo_here):
    stanzas, info = CASES["healthy"]
    d = admindir(tmp_path, stanzas, info)
    probes, memo = {"dpkg_audit": apt.dpkg_audit_probe(str(d))}, {"dpkg_audit": apt.dpkg_audit_inputs(str(d))}
    query = dict(probes=probes, memo=memo)

    def snapshot():
        out = subprocess.run(["sh", "-c", hoststate.snapshot_script(**query)], capture_output=True, text=True).stdout
        return hoststate.parse(out.splitlines(), query).probes["dpkg_audit"], "pblob" not in out

    assert snapshot() == ("", False)
    assert snapshot() == ("", True)  # answered from the memo
    (d / "info" / info[0]).unlink()  # a package's file list gone: the info directory changed
    assert snapshot() == (audit_now(d), False) and audit_now(d) != ""
    (d / "info" / info[0]).write_text("/.\n")
    assert snapshot() == ("", False)
    (d / "updates" / "0000").write_text(stanzas[0])  # an unfinished dpkg run
    assert snapshot() == ("dpkg journal not empty\n", False)
    assert snapshot() == ("dpkg journal not empty\n", True)
    (d / "updates" / "0000").unlink()
    (d / "status").write_text("\n".join([stanza("half", status="install reinstreq half-installed"), *stanzas]))
    assert snapshot() == (audit_now(d), False) and audit_now(d) != ""


LOGGED = ("stat", "sha256sum", "awk", "dpkg", "dpkg-query")


def kept_snapshot(tmp_path, files, packages=("dpkg", "coreutils")):
    """A snapshot of ``files`` and ``packages`` with the programs that read
    them logged: (its answer, the programs it started but the memo key's stat)."""
    bin_dir, log = tmp_path / "bin", tmp_path / "started"
    if not bin_dir.exists():
        bin_dir.mkdir()
        for name in LOGGED:
            real = subprocess.run(["sh", "-c", f"command -v {name}"], capture_output=True, text=True).stdout.strip()
            logged = f'[ "{name} $1" = "stat -L" ] || echo {name} >> {shlex.quote(str(log))}'  # not the key's stat
            (bin_dir / name).write_text(f'#!/bin/sh\n{logged}\nexec {real} "$@"\n')
            (bin_dir / name).chmod(0o755)
    log.write_text("")
    env = dict(os.environ, PATH=f"{bin_dir}:{os.environ['PATH']}")
    query = dict(files=[str(f) for f in files], packages=list(packages))
    out = subprocess.run(
        ["sh", "-c", hoststate.snapshot_script(**query)], capture_output=True, text=True, check=True, env=env
    ).stdout
    snap = hoststate.parse(out.splitlines(), query)
    return (snap.arch, dict(snap.files), dict(snap.packages)), sorted(set(log.read_text().split()))


def test_the_architecture_files_and_packages_are_kept_until_one_of_them_changes(tmp_path, memo_here):
    conf, rules, gone = tmp_path / "daemon.json", tmp_path / "rules", tmp_path / "later"
    conf.write_text('{"a": 1}\n')
    rules.mkdir()
    files = [conf, rules, gone]
    first, started = kept_snapshot(tmp_path, files)
    assert started == ["awk", "dpkg", "sha256sum", "stat"]
    assert first[0] and first[1][str(conf)].sha256 and first[1][str(gone)] is None and first[2]["dpkg"]
    assert kept_snapshot(tmp_path, files) == (first, [])  # nothing read again
    conf.write_text('{"a": 2}\n')  # the same size, another content
    again, started = kept_snapshot(tmp_path, files)
    assert started and again[1][str(conf)].sha256 != first[1][str(conf)].sha256
    assert kept_snapshot(tmp_path, files) == (again, [])
    gone.write_text("here now\n")  # a file that was missing
    assert kept_snapshot(tmp_path, files)[0][1][str(gone)].kind == "file"
    rules.chmod(0o700)  # a directory's mode
    assert kept_snapshot(tmp_path, files)[0][1][str(rules)].mode == "700"
    assert kept_snapshot(tmp_path, files)[1] == []
    assert kept_snapshot(tmp_path, files, packages=("dpkg",))[1]  # another question: another memo


def test_without_a_memo_everything_is_read_every_time(tmp_path, memo_here, monkeypatch):
    monkeypatch.setattr(snapshot_sh, "MEMO_OWNER", os.getuid() + 1)  # not this user's: no memo here
    files = [tmp_path / "f"]
    files[0].write_text("x\n")
    first, started = kept_snapshot(tmp_path, files)
    assert started == ["awk", "dpkg", "sha256sum", "stat"]
    assert kept_snapshot(tmp_path, files) == (first, started)


def test_the_packages_are_read_again_when_dpkg_s_database_changes(tmp_path, memo_here, monkeypatch):
    d = admindir(tmp_path, [stanza("a"), stanza("b")])
    monkeypatch.setattr(snapshot_sh, "DPKG_DIR", str(d))
    packages = ("a", "b")
    first, started = kept_snapshot(tmp_path, [], packages)
    assert first[2] == {"a": "1.0", "b": "1.0"} and "awk" in started
    assert kept_snapshot(tmp_path, [], packages) == (first, [])
    (d / "status").write_text((d / "status").read_text().replace("Version: 1.0", "Version: 2.0", 1))  # an upgrade
    again, started = kept_snapshot(tmp_path, [], packages)
    assert again[2] == {"a": "2.0", "b": "1.0"} and "awk" in started
    (d / "updates" / "0000").write_text(stanza("a"))  # an unfinished dpkg run: dpkg-query answers
    assert "dpkg-query" in kept_snapshot(tmp_path, [], packages)[1]
