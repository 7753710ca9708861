"""The on-robot release helper payloadctl, its pure parts in process: image
references, the release store's files, the update lock, and what the zip
application is made of.  It runs as a process, against stand-ins for docker
and systemctl, in tests/integration/test_payloadctl*.py."""

import os
import sys

import yaml

from roles.payload import installed_files as payload
from roles.payload.payloadctl import durable, imageref, images, lifecycle
from roles.payload.payloadctl import lock as apply_lock
from roles.payload.payloadctl import releases as store


def test_repository_of_references():
    assert imageref.repository("reg.lan:5000/ros/payload:1.0") == "reg.lan:5000/ros/payload"
    assert imageref.repository("reg.lan:5000/ros/payload@sha256:" + "a" * 64) == "reg.lan:5000/ros/payload"
    assert imageref.repository("ros/payload") == "ros/payload"


def test_pinned_prefers_the_digest_of_the_same_repository():
    info = {
        "id": "sha256:1",
        "repo_digests": ["other/x@sha256:" + "b" * 64, "reg.lan:5000/ros/payload@sha256:" + "a" * 64],
    }
    assert images.pinned("reg.lan:5000/ros/payload:1.0", info) == "reg.lan:5000/ros/payload@sha256:" + "a" * 64
    assert images.pinned("loaded/only:1.0", {"id": "sha256:1", "repo_digests": []}) == "loaded/only:1.0"


def test_pinned_keeps_the_digest_the_reference_names():
    """A pull release names each image by its signed digest: the release
    records that one, not another digest the same image was pulled under."""
    signed, other = "sha256:" + "c" * 64, "sha256:" + "a" * 64
    info = {
        "id": "sha256:1",
        "repo_digests": ["reg.lan:5000/ros/payload@" + other, "reg.lan:5000/ros/payload@" + signed],
    }
    assert images.pinned("reg.lan:5000/ros/payload:1.1@" + signed, info) == "reg.lan:5000/ros/payload@" + signed


def test_release_compose_is_yaml():
    doc = {"name": "p", "services": {"payload": {"image": "a/b@sha256:" + "c" * 64, "environment": {"A": "1"}}}}
    assert yaml.safe_load(store.compose_yaml(doc)) == doc


def test_a_release_file_grants_no_restart_policy_and_keeps_the_ones_asked_for():
    """Compose creates an unverified release's containers without a policy
    (a power cut must not bring them back before the boot decides); the
    policies wait in x-restart-when-verified for the verdict."""
    doc = {
        "name": "p",
        "services": {
            "payload": {"image": "a", "restart": "unless-stopped"},
            "driver": {
                "image": "b",
                "deploy": {
                    "restart_policy": {"condition": "on-failure", "max_attempts": 3},
                    "resources": {"limits": {"cpus": "1"}},
                },
            },
            "tool": {"image": "c"},
            "sidecar": {"image": "d", "restart": "always", "deploy": {"restart_policy": {"condition": "none"}}},
        },
    }
    asked = {"payload": "unless-stopped", "driver": "on-failure:3", "tool": "no", "sidecar": "no"}
    assert store.restart_policies(doc) == asked and not store.grants_no_policy(doc)
    written = yaml.safe_load(store.compose_yaml(store.release_compose(doc)))
    assert store.grants_no_policy(written)
    assert {name: s["restart"] for name, s in written["services"].items()} == dict.fromkeys(asked, "no")
    assert written["services"]["driver"]["deploy"] == {"resources": {"limits": {"cpus": "1"}}}
    assert store.restart_policies(written) == asked
    assert doc["services"]["payload"]["restart"] == "unless-stopped"  # the spec's document is left as it is


def test_update_lock_holder(tmp_path):
    lock = tmp_path / "update.lock"
    assert apply_lock.update_lock_holder(str(lock)) is None
    lock.write_text("robot is moving\n")
    assert apply_lock.update_lock_holder(str(lock)) == "robot is moving"
    lock.write_text("")
    assert apply_lock.update_lock_holder(str(lock)) == "no reason given"


def test_helper_runs_on_python_3_8_syntax():
    import ast

    for path in sorted(payload.PACKAGE.glob("*.py")):
        source = path.read_text()
        ast.parse(source, feature_version=(3, 8))  # Ubuntu 20.04 robots run Python 3.8
        assert "from __future__" not in source, path


def test_the_helper_uses_the_standard_library_and_its_own_modules_only():
    """It runs on robots without anything installed beside python3."""
    import ast

    allowed = set(sys.stdlib_module_names)
    for path in sorted(payload.PACKAGE.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level == 0:
                assert node.module.split(".")[0] in allowed, (path.name, node.module)
            elif isinstance(node, ast.Import):
                assert all(a.name.split(".")[0] in allowed for a in node.names), (path.name, ast.dump(node))


def test_the_helper_is_the_same_bytes_on_every_build():
    payload.helper_bytes.cache_clear()
    first = payload.helper_bytes()
    payload.helper_bytes.cache_clear()
    assert payload.helper_bytes() == first and first.startswith(b"#!/usr/bin/env python3\n")


def test_update_lock_is_never_followed_and_gives_one_printable_line(tmp_path):
    secret = tmp_path / "shadow"
    secret.write_text("root:$6$hash:19000:0:99999:7:::\n")
    lock = tmp_path / "update.lock"
    lock.symlink_to(secret)
    assert apply_lock.update_lock_holder(str(lock)) == "the lock is a symbolic link (not read)"
    lock.unlink()
    os.mkfifo(lock)
    assert apply_lock.update_lock_holder(str(lock)) == "the lock is not a regular file (not read)"
    lock.unlink()
    lock.write_text("moving\x1b[31m to dock " + "x" * 300 + "\nsecond line\n")
    reason = apply_lock.update_lock_holder(str(lock))
    assert reason.startswith("moving[31m to dock x") and len(reason) == 120 and "\n" not in reason
    assert all(ch.isprintable() for ch in reason)


def test_writes_are_fsynced_file_and_directory_before_they_count(tmp_path, monkeypatch):
    synced = []
    real_fsync = os.fsync

    def fsync(fd):
        synced.append(os.readlink(f"/proc/self/fd/{fd}"))
        real_fsync(fd)

    monkeypatch.setattr(durable.os, "fsync", fsync)
    life = lifecycle.Life(store.Releases(str(tmp_path)))
    (tmp_path / "releases" / "r1").mkdir(parents=True)
    life._write(lifecycle.Record(id="r1"))
    assert synced == [str(tmp_path / "releases" / "r1" / "record.json.tmp"), str(tmp_path / "releases" / "r1")]
    synced.clear()
    life._point("current", "r1")
    assert synced == [str(tmp_path)]
