"""`robotfleet export DIR` on a medium it does not trust
(robotfleet/pull/operator/medium.py): a reused stick whose ``metadata`` is a
symbolic link to a directory holding an SSH key, authorized_keys and the
fleet's online key, ``targets`` a link to another directory, a link deeper
down, a directory that is neither empty nor an earlier export: each refused
in one line naming it, before anything is signed or written, every file
they point at left as it was.  On an earlier export only the names an
export writes are replaced or deleted (the robots' reports and the
operator's own files stay), and a blob tampered with on the medium is
rewritten, never kept."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from robotfleet.pull.operator import export as exporting
from tests.integration.mediaworld import FLEET, media_fleet
from tests.integration.publishsite import git, robotfleet_cmd
from tests.unit import pullkit

SECRETS = {"id_ed25519": "-----BEGIN OPENSSH PRIVATE KEY-----\n", "authorized_keys": "ssh-ed25519 AAAA op\n"}


def secrets_dir(where: Path) -> dict[str, str]:
    where.mkdir(parents=True)
    files = {**SECRETS, "online.key": '{"keytype": "ed25519"}\n'}
    for name, text in files.items():
        (where / name).write_text(text)
    return files


def unchanged(where: Path, files: dict[str, str]) -> None:
    assert sorted(p.name for p in where.iterdir()) == sorted(files)
    for name, text in files.items():
        assert (where / name).read_text() == text


def copy_out(fleet, medium: Path) -> None:
    exporting.copy_out(fleet.repository, pullkit.module("operator.repository").Repository(medium))


def refused(fleet, medium: Path) -> str:
    with pytest.raises(pullkit.module("operator.medium").MediumError) as error:
        copy_out(fleet, medium)
    line = str(error.value)
    assert "\n" not in line
    return line


def test_export_onto_a_stick_whose_metadata_links_to_an_ssh_directory_refuses_and_deletes_nothing(
    site,
    image_registry,
    tmp_path,
):
    (site["checkout"] / "inventories" / "robots.yaml").write_text(FLEET.format(registry=image_registry[0]))
    git(site["checkout"], "commit", "-qam", "media fleet")
    common = ("--checkout", site["checkout"], "--keys", site["keys"])
    robotfleet_cmd("publish", *common, "--no-wheels")
    before = git(site["remote"], "rev-parse", "robotfleet/releases")
    home, other = tmp_path / "home-ssh", tmp_path / "elsewhere"
    files = secrets_dir(home)
    other.mkdir()
    (other / "notes.txt").write_text("mine\n")
    stick = tmp_path / "stick"
    stick.mkdir()
    (stick / "metadata").symlink_to(home)
    (stick / "targets").symlink_to(other)
    done = robotfleet_cmd("export", stick, *common, check=False)
    assert done.returncode != 0 and done.stderr.strip().count("\n") == 0, done.stderr
    assert f"{stick}/metadata: a symbolic link on the medium" in done.stderr, done.stderr
    unchanged(home, files)
    assert [p.name for p in other.iterdir()] == ["notes.txt"]
    assert git(site["remote"], "rev-parse", "robotfleet/releases") == before  # nothing re-signed or pushed


def test_a_targets_link_and_a_link_deeper_down_are_refused_naming_them(tmp_path):
    fleet = media_fleet(tmp_path)
    elsewhere = tmp_path / "elsewhere"
    files = secrets_dir(elsewhere)
    stick = tmp_path / "stick"
    copy_out(fleet, stick)  # an earlier export
    os.rename(stick / "targets", tmp_path / "old-targets")
    (stick / "targets").symlink_to(elsewhere)
    assert refused(fleet, stick).startswith(f"{stick}/targets: a symbolic link")
    unchanged(elsewhere, files)
    (stick / "targets").unlink()
    os.rename(tmp_path / "old-targets", stick / "targets")
    (stick / "targets" / "images").symlink_to(elsewhere)  # where the image archives go
    assert refused(fleet, stick).startswith(f"{stick}/targets/images: a symbolic link")
    (stick / "targets" / "images").unlink()
    (stick / "reports").mkdir()
    (stick / "reports" / "robot1.json").symlink_to(elsewhere / "id_ed25519")
    assert refused(fleet, stick).startswith(f"{stick}/reports/robot1.json: a symbolic link")
    unchanged(elsewhere, files)
    (stick / "reports" / "robot1.json").unlink()
    os.mkfifo(stick / "reports" / "robot2.json")
    assert "neither a file nor a directory" in refused(fleet, stick)


def test_a_directory_that_is_neither_empty_nor_an_earlier_export_is_refused(tmp_path):
    fleet = media_fleet(tmp_path)
    home = tmp_path / "home"
    files = secrets_dir(home / ".ssh")
    line = refused(fleet, home)
    assert line.startswith(f"{home}: neither empty nor an earlier export (it holds .ssh)"), line
    unchanged(home / ".ssh", files)
    assert sorted(p.name for p in home.iterdir()) == [".ssh"]
    new = tmp_path / "new-stick"
    (new / "lost+found").mkdir(parents=True)  # a freshly made ext4 file system
    copy_out(fleet, new)
    assert fleet.refresh(source=new).version == 1


def test_re_export_keeps_what_is_not_its_own_and_rewrites_a_tampered_blob(tmp_path):
    fleet = media_fleet(tmp_path)
    stick = tmp_path / "stick"
    copy_out(fleet, stick)
    (stick / "reports").mkdir()
    (stick / "reports" / "robot1.json").write_text("{}\n")
    (stick / "README.txt").write_text("the site's stick\n")
    (stick / "metadata" / "notes.json").write_text("{}\n")  # not a TUF name: not the export's
    blob = next((stick / "targets").glob("*.release.json"))
    signed = blob.read_bytes()
    blob.write_bytes(signed.replace(b'"version": 1', b'"version": 9'))
    copy_out(fleet, stick)  # the same release again: the blob is rewritten, not kept
    assert blob.read_bytes() == signed
    assert fleet.refresh(source=stick).version == 1
    fleet.release(2)
    copy_out(fleet, stick)
    assert fleet.refresh(source=stick).version == 2
    assert not blob.exists()  # release 1's record: the export's own, pruned
    assert (stick / "reports" / "robot1.json").read_text() == "{}\n"
    assert (stick / "README.txt").read_text() == "the site's stick\n"
    assert (stick / "metadata" / "notes.json").exists()
