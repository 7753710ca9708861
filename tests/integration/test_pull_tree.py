"""The deploy tree of a release (robotfleet/pull/protocol/tree.py) on real git
repositories: the content hash is the same from git's objects and from the
unpacked archive, the archive is the same bytes for the same commit, and
unpacking refuses anything that would land outside its directory."""

import hashlib
import io
import os
import subprocess
import tarfile

import pytest

from robotfleet.pull.protocol import tree


def git(where, *args):
    return subprocess.run(
        ["git", "-C", str(where), "-c", "user.name=t", "-c", "user.email=t@t", *args],
        check=True,
        capture_output=True,
        text=True,
    ).stdout.strip()


@pytest.fixture
def checkout(tmp_path):
    repo = tmp_path / "deploy"
    (repo / "roles" / "payload").mkdir(parents=True)
    (repo / "tests").mkdir()
    (repo / "deploy.py").write_text("ROLES = []\n")
    (repo / "roles" / "payload" / "__init__.py").write_text("x = 1\n")
    (repo / "roles" / "payload" / "run.sh").write_text("#!/bin/sh\n")
    os.chmod(repo / "roles" / "payload" / "run.sh", 0o755)
    os.symlink("payload/__init__.py", repo / "roles" / "link.py")
    (repo / "tests" / "test_x.py").write_text("not in a release\n")
    git(tmp_path, "init", "-q", str(repo))
    git(repo, "add", "-A")
    git(repo, "commit", "-qm", "one")
    return repo


def test_the_hash_from_git_and_from_the_unpacked_archive_agree(checkout, tmp_path):
    commit = tree.resolve(checkout, "HEAD")
    from_git = tree.entries_of_commit(checkout, commit)
    assert sorted(e.path for e in from_git) == [
        "deploy.py",
        "roles/link.py",
        "roles/payload/__init__.py",
        "roles/payload/run.sh",
    ]
    modes = {e.path: e.mode for e in from_git}
    assert (modes["roles/payload/run.sh"], modes["roles/link.py"], modes["deploy.py"]) == ("100755", "120000", "100644")
    assert {e.path: e.sha256 for e in from_git}["deploy.py"] == hashlib.sha256(b"ROLES = []\n").hexdigest()
    archive = tmp_path / "code.tar.gz"
    tree.write_archive(checkout, commit, archive)
    tree.unpack(archive, tmp_path / "unpacked")
    assert not (tmp_path / "unpacked" / "tests").exists()
    assert tree.tree_sha256(tree.entries_of_directory(tmp_path / "unpacked")) == tree.tree_sha256(from_git)


def test_a_mode_or_a_byte_changes_the_hash(checkout, tmp_path):
    first = tree.tree_sha256(tree.entries_of_commit(checkout, "HEAD"))
    os.chmod(checkout / "deploy.py", 0o755)
    git(checkout, "commit", "-qam", "executable")
    second = tree.tree_sha256(tree.entries_of_commit(checkout, "HEAD"))
    (checkout / "deploy.py").write_text("ROLES = [1]\n")
    git(checkout, "commit", "-qam", "content")
    third = tree.tree_sha256(tree.entries_of_commit(checkout, "HEAD"))
    assert len({first, second, third}) == 3
    tree.write_archive(checkout, "HEAD", tmp_path / "a.tar.gz")
    tree.unpack(tmp_path / "a.tar.gz", tmp_path / "u")
    (tmp_path / "u" / "roles" / "payload" / "__init__.py").write_text("x = 2\n")
    assert tree.tree_sha256(tree.entries_of_directory(tmp_path / "u")) != third


def test_the_archive_is_the_same_bytes_for_the_same_commit(checkout, tmp_path):
    commit = tree.resolve(checkout, "HEAD")
    one = tree.write_archive(checkout, commit, tmp_path / "one.tar.gz")
    clone = tmp_path / "clone"
    git(tmp_path, "clone", "-q", str(checkout), str(clone))
    os.utime(clone / "deploy.py", (0, 0))  # the working tree's times are not the archive's
    two = tree.write_archive(clone, commit, tmp_path / "two.tar.gz")
    assert one == two
    assert (tmp_path / "one.tar.gz").read_bytes() == (tmp_path / "two.tar.gz").read_bytes()
    git(checkout, "commit", "-q", "--allow-empty", "-m", "another commit, same tree")
    assert tree.write_archive(checkout, "HEAD", tmp_path / "three.tar.gz") != one  # the commit is in the archive


def test_a_commit_without_deploy_paths_is_refused(tmp_path):
    repo = tmp_path / "other"
    git(tmp_path, "init", "-q", str(repo))
    (repo / "README").write_text("x")
    git(repo, "add", "-A")
    git(repo, "commit", "-qm", "x")
    with pytest.raises(tree.TreeError, match="has none of deploy.py"):
        tree.write_archive(repo, "HEAD", tmp_path / "x.tar.gz")


def evil(tmp_path, name: str, member: tarfile.TarInfo, data: bytes = b"") -> str:
    path = tmp_path / name
    with tarfile.open(path, "w:gz") as archive:
        member.size = len(data)
        archive.addfile(member, io.BytesIO(data) if data else None)
    return path


@pytest.mark.parametrize(
    "make, says",
    [
        (lambda: tarfile.TarInfo("../escape.py"), "a path outside the archive's directory"),
        (lambda: tarfile.TarInfo("/etc/cron.d/x"), "a path outside the archive's directory"),
        (lambda: _link("roles/x", "/etc/shadow"), "a link to an absolute path"),
        (lambda: _link("roles/x", "../../etc"), "a link pointing outside the archive's directory"),
        (lambda: _kind("dev", tarfile.CHRTYPE), "not a file, directory or link"),
        (lambda: _kind("hard", tarfile.LNKTYPE), "not a file, directory or link"),
    ],
)
def test_unpacking_refuses_what_would_leave_its_directory(tmp_path, make, says):
    path = evil(tmp_path, "evil.tar.gz", make(), b"x" if make().isfile() else b"")
    with pytest.raises(tree.TreeError, match=says):
        tree.unpack(path, tmp_path / "out")
    assert not (tmp_path / "out").exists()
    assert [p.name for p in tmp_path.iterdir()] == ["evil.tar.gz"]  # no temp directory left


def _link(name, target):
    member = tarfile.TarInfo(name)
    member.type, member.linkname = tarfile.SYMTYPE, target
    return member


def _kind(name, kind):
    member = tarfile.TarInfo(name)
    member.type = kind
    member.linkname = "deploy.py" if kind == tarfile.LNKTYPE else ""
    return member


def test_a_link_within_the_tree_is_kept(tmp_path):
    path = evil(tmp_path, "ok.tar.gz", _link("roles/x", "../deploy.py"))
    tree.unpack(path, tmp_path / "out")
    assert os.readlink(tmp_path / "out" / "roles" / "x") == "../deploy.py"


def archive_of(path, *members: tarfile.TarInfo, data: bytes = b"x"):
    with tarfile.open(path, "w:gz") as archive:
        for member in members:
            member.size = len(data) if member.isfile() else 0
            archive.addfile(member, io.BytesIO(data) if member.isfile() else None)
    return path


def test_a_link_chain_cannot_carry_a_file_outside_the_tree(tmp_path):
    # Each link alone points inside by its text; l/l is the tree itself, so
    # l/l/up2 is two levels above it, and a file under it lands there.
    path = archive_of(
        tmp_path / "chain.tar.gz", _link("l", "."), _link("l/l/up2", "../.."), tarfile.TarInfo("l/l/up2/escaped.py")
    )
    destination = tmp_path / "a" / "b" / "out"
    destination.parent.mkdir(parents=True)
    with pytest.raises(tree.TreeError, match="chain.tar.gz: 'l/l/up2': a path through the link 'l'"):
        tree.unpack(path, destination)
    assert not (tmp_path / "a" / "escaped.py").exists()
    assert list(destination.parent.iterdir()) == []


@pytest.mark.parametrize(
    "members",
    [
        [("a", "."), ("b", "a/a/..")],  # b's text stays inside; through a it is the tree's parent
        [("b", "l/.."), ("l", ".")],  # the same, with the link b goes through made after b
    ],
)
def test_a_link_resolving_outside_through_other_links_is_refused(tmp_path, members):
    path = archive_of(tmp_path / "links.tar.gz", *(_link(name, target) for name, target in members))
    with pytest.raises(tree.TreeError, match="'b': a link resolving outside the archive's directory"):
        tree.unpack(path, tmp_path / "out")
    assert [p.name for p in tmp_path.iterdir()] == ["links.tar.gz"]


def test_unpacking_never_replaces_an_existing_directory(checkout, tmp_path):
    tree.write_archive(checkout, "HEAD", tmp_path / "a.tar.gz")
    (tmp_path / "out").mkdir()
    with pytest.raises(tree.TreeError, match="already exists"):
        tree.unpack(tmp_path / "a.tar.gz", tmp_path / "out")
