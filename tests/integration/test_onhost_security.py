"""Issue 8, the on-host half: the generated shell scripts run for real here
(sh, gpg, curl on file:// URLs) so what is proven is what runs on a robot.
What the roles plan is checked in tests/unit/test_onhost_plans.py."""

from __future__ import annotations

import subprocess

import pytest

from robotfleet.host import aptrepo
from robotfleet.host.snapshot import FileState, HostSnapshot, Snapshot
from tests import armor
from tests.fixtures import me, run_command, sh
from tests.unit.harness import docker_repo


def _new_key(tmp_path, name: str, with_subkey: bool = False) -> tuple[str, bytes]:
    """A fresh key (fingerprint, armored public key) in its own keyring."""
    home = tmp_path / f"gnupg-{name}"
    fingerprint = armor.new_key(home, f"{name}@example", with_subkey)
    return fingerprint, armor.gpg(home, "--armor", "--export").stdout


@pytest.fixture(scope="module")
def keys(tmp_path_factory):
    """The pinned key (with a subkey, like Docker's) and an intruder's key."""
    base = tmp_path_factory.mktemp("keys")
    pinned = _new_key(base, "pinned", with_subkey=True)
    intruder = _new_key(base, "intruder")
    return pinned, intruder


def _probe(dest, pin) -> aptrepo.InstalledKey:
    return aptrepo.installed_key(sh(aptrepo.key_probe(str(dest), pin)).stdout)


def _snap(path, probe_output: str) -> Snapshot:
    """A snapshot in which the key file is in place (0644) and the probe said ``probe_output``."""
    return Snapshot(
        files={str(path): FileState("file", "a" * 64, "644", "root", "root")},
        probes={"docker_key_fingerprints": probe_output},
    )


def test_the_probe_lists_primary_keys_only(tmp_path, keys):
    (fpr, key), _ = keys
    dest = tmp_path / "docker.asc"
    dest.write_bytes(key)
    # the subkey's fingerprint is not a key of its own
    assert _probe(dest, fpr) == aptrepo.InstalledKey((fpr,), canonical=True)


def test_a_key_file_holding_a_second_key_is_refused(tmp_path, keys):
    (fpr, key), (other, intruder) = keys
    served = tmp_path / "gpg"
    served.write_bytes(key + intruder)
    dest = tmp_path / "keyrings" / "docker.asc"
    dest.parent.mkdir()
    proc = sh(aptrepo.key_script(docker_repo(f"file://{served}", str(dest), fpr, None)))
    assert proc.returncode == 1
    assert proc.stderr.count("\n") == 1, proc.stderr  # one line
    assert (
        f"holds 2 keys ({fpr} {other}); only docker_apt_key_fingerprint {fpr} may be in it; key not installed"
    ) in proc.stderr
    assert list(dest.parent.iterdir()) == []


def test_a_poisoned_keyring_on_the_host_is_not_current_and_is_replaced(tmp_path, keys):
    (fpr, key), (other, intruder) = keys
    dest = tmp_path / "keyrings" / "docker.asc"
    dest.parent.mkdir()
    dest.write_bytes(key + intruder)
    dest.chmod(0o644)
    probe = sh(aptrepo.key_probe(str(dest), fpr)).stdout
    assert aptrepo.installed_key(probe) == aptrepo.InstalledKey((fpr, other), canonical=False)
    assert not aptrepo.key_is_current(docker_repo("", str(dest), fpr, None), _snap(dest, probe))
    assert aptrepo.key_is_current(docker_repo("", str(dest), fpr, None), _snap(dest, f"{fpr}\n{aptrepo.CANONICAL}\n"))
    served = tmp_path / "gpg"
    served.write_bytes(key)
    proc = sh(aptrepo.key_script(docker_repo(f"file://{served}", str(dest), fpr, None)))
    assert proc.returncode == 0, proc.stderr
    assert _probe(dest, fpr) == aptrepo.InstalledKey((fpr,), canonical=True)
    assert dest.read_bytes() == key  # the fixture's key is gpg's own armored export


def test_a_poisoned_keyring_is_removed_even_when_the_mirror_still_serves_two_keys(tmp_path, keys):
    """Fail closed: apt must not go on trusting the intruder's key."""
    (fpr, key), (_, intruder) = keys
    dest = tmp_path / "keyrings" / "docker.asc"
    dest.parent.mkdir()
    dest.write_bytes(intruder + key)
    served = tmp_path / "gpg"
    served.write_bytes(intruder + key)
    proc = sh(aptrepo.key_script(docker_repo(f"file://{served}", str(dest), fpr, None)))
    assert proc.returncode == 1 and "key not installed" in proc.stderr
    assert list(dest.parent.iterdir()) == []


def test_a_single_good_key_is_kept_when_the_download_is_refused(tmp_path, keys):
    (fpr, key), (_, intruder) = keys
    dest = tmp_path / "keyrings" / "docker.asc"
    dest.parent.mkdir()
    dest.write_bytes(key)
    served = tmp_path / "gpg"
    served.write_bytes(key + intruder)
    assert sh(aptrepo.key_script(docker_repo(f"file://{served}", str(dest), fpr, None))).returncode == 1
    assert dest.read_bytes() == key


def _nvidia_repo(url: str, key_path: str, fingerprint: str) -> aptrepo.Repository:
    """NVIDIA's repository as the gpu role declares it (no sha256 setting)."""
    from roles import gpu
    from tests.unit.harness import merged

    data = merged(
        "robots",
        {
            "gpu_vendor": "nvidia",
            "gpu_apt_key_url": url,
            "gpu_apt_key_path": key_path,
            "gpu_apt_key_fingerprint": fingerprint,
        },
    )
    return gpu.repository(data, "amd64")


@pytest.mark.parametrize("payload", ["$(touch${IFS}%s)", "`touch${IFS}%s`", '"$(touch${IFS}%s)"'])
def test_the_key_url_is_never_run_on_the_mismatch_paths(tmp_path, keys, payload):
    """Every message that prints the URL (download failed, fingerprint,
    sha256), Docker's and NVIDIA's: none runs it."""
    (fpr, key), _ = keys
    served = tmp_path / "gpg"
    served.write_bytes(key)
    pwned = tmp_path / "pwned"
    url = f"file://{served}?x=" + payload % pwned
    missing = f"file://{tmp_path}/missing?x=" + payload % pwned
    assert subprocess.run(["curl", "-fsS", url], capture_output=True).returncode == 0  # the mismatch path is reached
    dest = tmp_path / "docker.asc"
    mismatch, download = "key not installed", "cannot download"
    repos = [
        (docker_repo(url, str(dest), fingerprint, sha256), mismatch)
        for fingerprint, sha256 in (("DEAD" * 10, None), (None, "0" * 64), (fpr, "0" * 64))
    ]
    repos += [
        (_nvidia_repo(url, str(dest), "DEAD" * 10), mismatch),
        (_nvidia_repo(missing, str(dest), fpr), download),
        (docker_repo(missing, str(dest), fpr), download),
    ]
    for repo, message in repos:
        proc = sh(aptrepo.key_script(repo))
        assert proc.returncode == 1, proc.stderr
        assert repo.key_url in proc.stderr and message in proc.stderr, proc.stderr
        assert not pwned.exists(), f"the URL ran as a command: {proc.stderr}"
    assert not dest.exists()


# --- symlinks where a managed file or directory is wanted (items 7, 8) ------


def test_the_snapshot_reports_a_symlink_as_a_link(tmp_path):
    (tmp_path / "target").write_text("{}\n")
    (tmp_path / "dir").mkdir()
    for name, target in (("to-file", "target"), ("to-dir", "dir"), ("dangling", "nowhere")):
        (tmp_path / name).symlink_to(tmp_path / target)
    paths = [str(tmp_path / n) for n in ("to-file", "to-dir", "dangling", "target", "dir")]
    fact = HostSnapshot()
    out = sh(fact.command(files=paths), check=True)
    snap = fact.process(out.stdout.splitlines())
    kinds = {p.rsplit("/", 1)[1]: (snap.files[p].kind if snap.files[p] else None) for p in paths}
    assert kinds == {"to-file": "link", "to-dir": "link", "dangling": "link", "target": "file", "dir": "dir"}


@pytest.mark.parametrize("target_kind", ["file", "dir"])
def test_writing_a_file_replaces_a_symlink_and_leaves_its_target_alone(tmp_path, target_kind):
    from robotfleet.host import operations

    target = tmp_path / "elsewhere"
    if target_kind == "file":
        target.write_text("not yours\n")
    else:
        target.mkdir()
    dest = tmp_path / "etc" / "daemon.json"
    dest.parent.mkdir()
    dest.symlink_to(target)
    proc = run_command(operations.write_file_command(str(dest), b"{}\n", "0644", *me()))
    assert proc.returncode == 0, proc.stderr
    assert not dest.is_symlink() and dest.read_bytes() == b"{}\n"
    if target_kind == "file":
        assert target.read_text() == "not yours\n"
    else:
        assert list(target.iterdir()) == []


def test_the_directory_command_itself_refuses_a_symlink(tmp_path):
    """The snapshot is a moment ago: the command checks again before install -d/chmod."""
    from robotfleet.host import operations

    real = tmp_path / "real"
    real.mkdir(mode=0o1777)
    real.chmod(0o1777)
    link = tmp_path / "link"
    link.symlink_to(real)
    command = operations.directory_command(str(link), "0755", "root", "root")
    proc = run_command(command)
    assert proc.returncode == 1 and "is a symbolic link" in proc.stderr
    assert oct(real.stat().st_mode)[-4:] == "1777"


# --- push: the image goes over the command's stdin, no path on the robot (item 6)


def test_the_pushed_archive_goes_over_stdin_intact_through_pyinfras_writer(tmp_path):
    """pyinfra's own write_stdin sends it, a real base64 -d reads it back."""
    import os

    from pyinfra.connectors.util import write_stdin

    from robotfleet.host.stream import FileStdin
    from roles.payload import image_transfer

    archive = tmp_path / "image.tar"
    archive.write_bytes(os.urandom(3 * FileStdin.CHUNK + 12345))
    command = image_transfer.load_command(
        str(archive), "/var/lib/robot-payload", "reg.lan/ros/payload:1.0", "sha256:a", {}
    )
    raw = command.get_raw_value()
    assert "base64 -d | docker load" in raw
    assert "/tmp" not in raw and "robotprov-image" not in raw and "-i " not in raw
    stdin = command.connector_arguments["_stdin"]
    assert stdin  # pyinfra only writes a truthy stdin
    # Sent twice (pyinfra sends stdin again when sudo asks for a password):
    # the whole archive each time, read afresh from disk.
    for attempt in ("first", "second"):
        received = tmp_path / f"received-{attempt}"
        with open(received, "wb") as sink:
            proc = subprocess.Popen(["base64", "-d"], stdin=subprocess.PIPE, stdout=sink)
            write_stdin(stdin, proc.stdin)
            assert proc.wait(timeout=60) == 0
        assert received.read_bytes() == archive.read_bytes(), attempt


# --- daemon.json may hold proxy credentials: root's alone (issue 27, item 7) ---


def test_daemon_json_and_its_previous_copy_are_written_0600_whatever_the_old_mode(tmp_path):
    """The write script runs for real (sh, this machine's dockerd): an old
    0644 daemon.json holding a proxy password is kept as .previous 0600 (not
    copied with its mode), and the new file is 0600 too."""
    import base64
    import os
    import stat

    from roles.docker import daemon

    dest = tmp_path / "daemon.json"
    previous, pending = tmp_path / "daemon.json.previous", tmp_path / "daemon.json.pending"
    old = '{"proxies": {"http-proxy": "http://u:s3cret@proxy:3128"}}\n'
    dest.write_text(old)
    os.chmod(dest, 0o644)
    new = base64.encodebytes(b'{"live-restore": true}\n').decode()
    proc = subprocess.run(
        ["sh", "-c", daemon.write_script(str(dest), str(previous), str(pending))],
        input=new,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 0, proc.stderr
    assert dest.read_text() == '{"live-restore": true}\n' and previous.read_text() == old
    for path in (dest, previous):
        info = path.stat()
        assert (stat.S_IMODE(info.st_mode), info.st_uid, info.st_gid) == (0o600, 0, 0), path
