"""The generated scripts of tests/unit/test_rendering.py run for real by sh
on this machine: the snapshot, the key download, a file write, the x11
cookie script's syntax."""

import os
import platform
import re

from robotfleet.host import aptrepo, snapshot_sh
from robotfleet.host import snapshot as hoststate
from roles import x11
from tests import armor
from tests.fixtures import me, run_command, sh
from tests.unit.harness import docker_repo, merged


def test_snapshot_script_runs_on_a_real_shell(tmp_path):
    (tmp_path / "f").write_text("hello\n")
    (tmp_path / "f").chmod(0o640)
    (tmp_path / "d").mkdir()
    query = dict(
        files=[str(tmp_path / "f"), str(tmp_path / "d"), str(tmp_path / "missing file")],
        packages=["dpkg", "surely-not-a-package"],
        users=["root", "surely-not-a-user"],
        commands=["sh", "surely-not-a-command"],
        probes={
            "two lines": "echo a; echo 'b c'",
            "fails": "false",
            "exits": "echo before; exit 3; echo after",
            "traps": "trap 'echo trapped' EXIT; echo body",
            "assigns": "i=0; D=/nonexistent; sleep 0.2; echo mine",
        },
    )
    out = sh(hoststate.snapshot_script(**query), check=True)
    snap = hoststate.parse(out.stdout.splitlines(), query)
    # This machine's own answers, read here another way.
    assert snap.os_release == {key.lower(): value for key, value in platform.freedesktop_os_release().items()}
    assert snap.arch == sh("dpkg --print-architecture", check=True).stdout.strip() != ""
    assert "dpkg" in snap.packages and "surely-not-a-package" not in snap.packages
    f = snap.files[str(tmp_path / "f")]
    assert f.kind == "file" and f.mode == "640"
    assert f.sha256 == "5891b5b522d5df086d0ff0b110fbd9d21bb4fc7163af34d08286a2e846f6be03"
    assert snap.files[str(tmp_path / "d")].kind == "dir"
    assert snap.files[str(tmp_path / "missing file")] is None
    assert "root" in snap.users["root"] and snap.users["surely-not-a-user"] is None
    assert snap.commands["sh"] and snap.commands["surely-not-a-command"] is None
    assert snap.probes["two lines"] == "a\nb c\n" and snap.probes["fails"] == ""
    # A probe that exits, or sets a trap of its own, is still read whole.
    assert snap.probes["exits"] == "before\n" and snap.probes["traps"] == "body\ntrapped\n"
    assert snap.probes["assigns"] == "mine\n"  # its own i and D: still its own answer, the others theirs


def _all_kinds_of_paths(tmp_path) -> list[str]:
    (tmp_path / "f").write_text("hello\n")
    (tmp_path / "empty").write_text("")
    (tmp_path / "d").mkdir()
    (tmp_path / "link").symlink_to(tmp_path / "f")
    os.mkfifo(tmp_path / "fifo")
    return [str(tmp_path / name) for name in ("f", "empty", "d", "link", "fifo", "missing")]


def test_snapshot_reads_files_in_one_stat_as_it_would_one_by_one(tmp_path, monkeypatch):
    paths = _all_kinds_of_paths(tmp_path)
    query = dict(files=paths, probes={"p": "echo p"}, units=["surely-not-a.service"])

    def files():
        out = sh(hoststate.snapshot_script(**query), check=True)
        snap = hoststate.parse(out.stdout.splitlines(), query)
        return {path: snap.files[path] for path in paths}, out.stdout

    batched, text = files()
    assert "\nstat\t" in "\n" + text and "\nfile\t" not in "\n" + text
    monkeypatch.setattr(snapshot_sh, "PLAIN_PATH", re.compile(r"(?!)"))  # every path on its own
    one_by_one, text = files()
    assert "\nfile\t" in "\n" + text
    assert batched == one_by_one
    kinds = {path.rsplit("/", 1)[1]: state and (state.kind, state.sha256) for path, state in batched.items()}
    assert kinds == {
        "f": ("file", "5891b5b522d5df086d0ff0b110fbd9d21bb4fc7163af34d08286a2e846f6be03"),
        "empty": ("file", "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855"),
        "d": ("dir", None),
        "link": ("link", None),
        "fifo": None,
        "missing": None,
    }


def test_snapshot_runs_its_slow_reads_one_after_another_without_a_temporary_directory(tmp_path):
    fake = tmp_path / "bin"
    fake.mkdir()
    (fake / "mktemp").write_text("#!/bin/sh\nexit 1\n")
    (fake / "mktemp").chmod(0o755)
    query = dict(probes={"a": "echo a", "b": "echo b"}, packages=["dpkg"])
    env = dict(os.environ, PATH=f"{fake}:{os.environ['PATH']}")
    out = sh(hoststate.snapshot_script(**query), check=True, env=env)
    snap = hoststate.parse(out.stdout.splitlines(), query)
    assert snap.probes["a"] == "a\n" and snap.probes["b"] == "b\n" and "dpkg" in snap.packages


def test_key_download_verifies_before_moving_into_place(tmp_path):
    """Run the real download script against a local file:// key with a wrong pin."""
    key = tmp_path / "key.asc"
    key.write_text("not really a key\n")
    dest = tmp_path / "keyrings" / "docker.asc"
    dest.parent.mkdir()
    script = aptrepo.key_script(docker_repo(f"file://{key}", str(dest), None, "0" * 64))
    proc = sh(script)
    assert proc.returncode == 1 and "does not match docker_apt_key_sha256" in proc.stderr
    assert list(dest.parent.iterdir()) == []  # nothing half-written left behind
    good = sh(f"sha256sum {key}").stdout.split()[0]
    proc = sh(aptrepo.key_script(docker_repo(f"file://{key}", str(dest), None, good)))
    assert proc.returncode == 0, proc.stderr
    assert dest.read_text() == "not really a key\n" and oct(dest.stat().st_mode)[-3:] == "644"


def test_file_write_is_atomic_and_validated_before_it_lands(tmp_path):
    """The real write command: a failing check leaves the old file untouched."""
    from robotfleet.host import operations

    dest = tmp_path / "etc" / "x.conf"

    def run(content, validate=None):
        return run_command(operations.write_file_command(str(dest), content, "0640", *me(), validate))

    assert run(b"first\n").returncode == 0
    assert dest.read_bytes() == b"first\n" and oct(dest.stat().st_mode)[-3:] == "640"
    proc = run(b"second\n", validate="grep -q first {}")
    assert proc.returncode != 0
    assert dest.read_bytes() == b"first\n"
    assert sorted(p.name for p in dest.parent.iterdir()) == ["x.conf"]


def test_key_fingerprint_pin_with_real_gpg(tmp_path):
    """The download script and the snapshot probe read fingerprints the same way."""
    home = tmp_path / "gnupg"
    fingerprint = armor.new_key(home, "lab@example")
    (tmp_path / "key.asc").write_bytes(armor.gpg(home, "--armor", "--export").stdout)
    dest = tmp_path / "keyrings" / "docker.asc"
    dest.parent.mkdir()
    url = f"file://{tmp_path}/key.asc"
    wrong = sh(aptrepo.key_script(docker_repo(url, str(dest), "DEAD" * 10, None)))
    assert wrong.returncode == 1 and f"fingerprint {fingerprint} does not match" in wrong.stderr
    assert list(dest.parent.iterdir()) == []
    right = sh(aptrepo.key_script(docker_repo(url, str(dest), fingerprint, None)))
    assert right.returncode == 0, right.stderr
    probe = sh(aptrepo.key_probe(str(dest), fingerprint))
    assert aptrepo.installed_key(probe.stdout) == aptrepo.InstalledKey((fingerprint,), canonical=True)


def test_a_stalled_probe_is_cut_off_and_the_snapshot_still_answers(monkeypatch):
    """A wedged dockerd makes `docker ps` hang: one probe must not hang the
    host's only snapshot command (and so every later deploy of that robot)."""
    monkeypatch.setattr(snapshot_sh, "PROBE_TIMEOUT", 1)
    query = dict(probes={"stalls": "sleep 30; echo late", "answers": "echo ok"})
    out = sh(hoststate.snapshot_script(**query), check=True, timeout=20)
    snap = hoststate.parse(out.stdout.splitlines(), query)
    assert snap.probes["stalls"] == "" and snap.probes["answers"] == "ok\n"


def test_x11_cookie_script_is_valid_sh():
    script = x11.cookie_script(merged("laptops", {"x11_user": "alice"}))
    proc = sh("sh -n", input=script)
    assert proc.returncode == 0, proc.stderr
