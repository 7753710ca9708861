"""First-boot bundles (robotfleet/pull/operator/bundle.py): what goes on a robot's
image, owned by root with its secrets 0600, and the first-boot script."""

from __future__ import annotations

import json
import subprocess
import sys
import tarfile
from pathlib import Path
from types import SimpleNamespace

import pytest

from robotfleet.pull.operator import bundle
from robotfleet.pull.protocol import agent_files

KEY = "ssh-ed25519 AAAAC3NzaC1lZDI1NTE5AAAAIGbigA6mqsYKDD3V4SGhrWodxIaju5HYfXtBYAQEvqW0"
DATA = SimpleNamespace(
    pull_remote="ssh://gitolite3@git.lan/fleet",
    pull_interval=60,
    pull_jitter=5,
    pull_windows=[],
    pull_min_free_mb=256,
    pull_fetch_timeout=120,
    pull_stale_after=3,
    pull_boot_delay=30,
    pull_remote_host_keys=[KEY],
    pull_platform="cp313-x86_64",
    pull_heartbeat=3600,
    pull_report_remote=None,
    pull_remote_ca=None,
)
DATA.pull_report_shards = 0
RECORD = SimpleNamespace(version=4, published="2026-11-25T10:00:00Z", tree_sha256="ab" * 32)


@pytest.fixture
def made(tmp_path):
    code = tmp_path / "code.tar.gz"
    code.write_bytes(b"code")
    wheel = tmp_path / "w.whl"
    wheel.write_bytes(b"wheel")
    public = bundle.make(
        tmp_path / "out", "robot9", DATA, RECORD, code, [("pyinfra-3.10-py3-none-any.whl", wheel)], b'{"root": 1}'
    )
    return tmp_path / "out", public


def test_the_bundle_holds_the_robot_s_agent_its_trust_and_a_first_boot(made):
    out, public = made
    with tarfile.open(out / "rootfs.tar") as tar:
        members = {m.name: m for m in tar.getmembers()}
        read = lambda name: tar.extractfile(members[name]).read()  # noqa: E731
        config = agent_files.read_config(read("etc/robot-pull/agent.json").decode())
        assert (config.robot, config.remote, config.interval) == ("robot9", DATA.pull_remote, 60)
        assert config.extra == {"trusted_time": "2026-11-25T10:00:00Z"}  # no clock older than the release is believed
        assert read("etc/robot-pull/root.json") == b'{"root": 1}'
        assert read("etc/robot-pull/known_hosts").decode() == f"robotfleet-remote {KEY}\n"
        assert read("etc/robot-pull/enroll_ed25519.pub").decode().startswith(public)
        assert read("var/lib/robot-pull/first-boot/tree-id").decode().strip() == RECORD.tree_sha256
        assert read("var/lib/robot-pull/first-boot/wheels/pyinfra-3.10-py3-none-any.whl") == b"wheel"
        assert b"OnBootSec=30" in read("etc/systemd/system/robot-pull.timer")
        assert (
            members["etc/systemd/system/multi-user.target.wants/robot-pull-first-boot.service"].linkname
            == "../robot-pull-first-boot.service"
        )
        assert members["etc/systemd/system/timers.target.wants/robot-pull.timer"].issym()
        for name, member in members.items():
            assert (member.uid, member.gid) == (0, 0), name
        for secret in ("etc/robot-pull/agent.json", "etc/robot-pull/root.json", "etc/robot-pull/enroll_ed25519"):
            assert members[secret].mode & 0o077 == 0, secret
        assert members["etc/robot-pull"].mode & 0o077 == 0 and members["var/lib/robot-pull"].mode & 0o077 == 0
        assert members["usr/local/sbin/robot-pull-first-boot"].mode == 0o755
    assert (out / "rootfs.tar").stat().st_mode & 0o077 == 0
    assert "tar -xpf rootfs.tar -C /mnt/image" in (out / "README").read_text()
    assert not (out / "rootfs").exists()


def test_the_first_boot_script_is_valid_sh_and_does_its_steps_in_order():
    script = bundle.FIRST_BOOT_SCRIPT
    assert subprocess.run(["sh", "-n"], input=script, text=True).returncode == 0
    order = [
        script.index(step)
        for step in (
            "ssh-keygen -A",
            "python3 -m venv",
            "tar -xzf",
            'rm -rf "$fb"',
            "systemctl start --no-block robot-pull.service",
        )
    ]
    assert order == sorted(order)
    assert "ConditionPathExists=/var/lib/robot-pull/first-boot" in bundle.FIRST_BOOT_UNIT


def test_a_bundle_needs_wheels_and_a_new_directory(tmp_path, made):
    out, _ = made
    with pytest.raises(bundle.BundleError, match="already exists"):
        bundle.make(out, "robot9", DATA, RECORD, tmp_path / "code.tar.gz", [("w.whl", tmp_path / "w.whl")], b"{}")
    with pytest.raises(bundle.BundleError, match="carries no wheels for cp313-x86_64"):
        bundle.make(tmp_path / "new", "robot9", DATA, RECORD, tmp_path / "code.tar.gz", [], b"{}")


def test_the_operator_keeps_only_the_hash_of_the_enrollment_key(tmp_path):
    path = tmp_path / ".robotfleet" / "enrollments.json"
    bundle.remember(path, "robot9", KEY + " robot-pull-enroll@robot9", 4)
    kept = json.loads(path.read_text())
    assert kept == {"robot9": {"enroll_key_sha256": bundle.key_sha256(KEY), "release": 4}}
    assert KEY.split()[1] not in path.read_text()


def test_the_gitolite_repository_a_remote_names():
    from robotfleet.commands.pull.bundle import repository_name

    assert repository_name("ssh://gitolite3@git.lan:2222/fleet") == "fleet"
    assert repository_name("git@git.lan:robots/fleet.git") == "robots/fleet"


def test_a_bundle_for_an_image_shared_by_many_robots_carries_the_name_rule(tmp_path):
    code = tmp_path / "code.tar.gz"
    code.write_bytes(b"code")
    bundle.make(tmp_path / "out", "robot9", DATA, RECORD, code, [("w.whl", code)], b"{}", None, ("machine-id", "arm-"))
    with tarfile.open(tmp_path / "out" / "rootfs.tar") as tar:
        text = tar.extractfile("etc/robot-pull/agent.json").read().decode()
    config = agent_files.read_config(text)
    assert (config.robot, config.name_rule, config.name_prefix, config.interval) == ("", "machine-id", "arm-", 60)
    assert agent_files.named(config, read=lambda rule: "0123456789abcdef0123456789abcdef\n").robot == "arm-0123456789ab"
    assert "arm-<machine-id> (with the settings of robot9)" in (tmp_path / "out" / "README").read_text()


def test_under_a_loose_umask_the_image_s_directories_keep_their_modes(tmp_path):
    # The operator's umask 002 (a shared group): the bundle is made in a
    # process that has it, then unpacked as docs/guides/pull.md says onto an image
    # whose /etc, /usr and /var are 0755.
    code = tmp_path / "code.tar.gz"
    code.write_bytes(b"code")
    made = (
        "import os, sys; from pathlib import Path; os.umask(0o002); "
        "from robotfleet.pull.operator import bundle; from tests.integration.test_pull_bundle import DATA, RECORD; "
        "code = Path(sys.argv[1]); "
        "bundle.make(Path(sys.argv[2]), 'robot9', DATA, RECORD, code, [('w.whl', code)], b'{}')"
    )
    subprocess.run(
        [sys.executable, "-c", made, str(code), str(tmp_path / "out")],
        check=True,
        cwd=Path(__file__).resolve().parents[2],
    )
    with tarfile.open(tmp_path / "out" / "rootfs.tar") as tar:
        members = tar.getmembers()
    directories = sorted(m.name for m in members if m.isdir())
    assert directories == [
        "etc/robot-pull",
        "var/lib/robot-pull",
        "var/lib/robot-pull/first-boot",
        "var/lib/robot-pull/first-boot/wheels",
    ]
    assert [(m.name, oct(m.mode)) for m in members if not m.issym() and m.mode & 0o022] == []
    image = tmp_path / "image"
    for top in ("etc", "usr", "var"):
        (image / top).mkdir(parents=True)
        (image / top).chmod(0o755)
    # root's usual umask makes the directories the image lacks (etc/systemd/system/timers.target.wants)
    subprocess.run(
        ["sh", "-c", 'umask 022 && tar -xpf "$0" -C "$1"', tmp_path / "out" / "rootfs.tar", image], check=True
    )
    loose = [
        str(path.relative_to(image))
        for path in image.rglob("*")
        if not path.is_symlink() and path.stat().st_mode & 0o022
    ]
    assert loose == []
    assert (image / "etc").stat().st_mode & 0o777 == 0o755
    assert (image / "usr/local/sbin/robot-pull-first-boot").stat().st_mode & 0o777 == 0o755


def test_a_new_bundle_for_an_enrolled_robot_keeps_the_key_it_was_enrolled_with(tmp_path):
    from robotfleet.pull.operator import enrollments

    path = tmp_path / "enrollments.json"
    bundle.remember(path, "robot9", KEY, 4)
    enrollments.record(path, "robot9", KEY)
    bundle.remember(path, "robot9", KEY.replace("AAAAIGbig", "AAAAIGbiX"), 5)  # a new bundle: a new enrollment key
    kept = enrollments.read_kept(path)
    assert enrollments.enrolled_key(kept, "robot9") == bundle.key_sha256(KEY)  # a second key stays refused
    assert kept["robot9"]["release"] == 5 and path.stat().st_mode & 0o077 == 0
