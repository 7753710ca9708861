"""robotfleet/atomicfile.py: whole or not at all."""

import os

import pytest

from robotfleet import atomicfile


def test_replaces_with_the_mode_asked_and_leaves_no_temp_file(tmp_path):
    target = tmp_path / "state.json"
    target.write_text("old")
    atomicfile.write(target, "new", mode=0o644)
    assert target.read_text() == "new" and (target.stat().st_mode & 0o777) == 0o644
    assert sorted(p.name for p in tmp_path.iterdir()) == ["state.json"]


def test_without_a_mode_the_file_is_the_owners_alone_and_parents_are_made_when_asked(tmp_path):
    target = tmp_path / "a" / "b" / "trust.json"
    with pytest.raises(FileNotFoundError):
        atomicfile.write(target, b"x")
    atomicfile.write(target, b"x", make_parents=True)
    assert target.read_bytes() == b"x" and (target.stat().st_mode & 0o777) == 0o600


def test_a_failed_write_keeps_the_old_file_and_removes_the_temp_file(tmp_path, monkeypatch):
    target = tmp_path / "metrics.prom"
    target.write_text("old")

    def full_disk(fd):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", full_disk)
    with pytest.raises(OSError, match="No space left"):
        atomicfile.write(target, "new")
    assert target.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["metrics.prom"]


def test_keep_mode_keeps_the_mode_of_the_file_there_and_gives_a_new_one_the_mode_asked(tmp_path):
    there = tmp_path / "known_hosts"
    there.write_text("old")
    there.chmod(0o640)
    atomicfile.write(there, "new", mode=0o644, keep_mode=True)
    assert there.read_text() == "new" and (there.stat().st_mode & 0o777) == 0o640
    new = tmp_path / "ssh" / "known_hosts"
    atomicfile.write(new, "new", mode=0o644, make_parents=True, keep_mode=True)
    assert (new.stat().st_mode & 0o777) == 0o644
    assert sorted(p.name for p in tmp_path.iterdir()) == ["known_hosts", "ssh"]
