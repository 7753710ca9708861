"""Issue 8, the on-host half: the generated shell scripts run for real here
(sh, gpg, curl on file:// URLs) so what is proven is what runs on a robot."""

from __future__ import annotations

import subprocess

import pytest

from robotfleet.host import aptrepo
from robotfleet.host.snapshot import FileState, HostSnapshot, Snapshot
from tests import armor
from tests.unit.harness import desired_compose, docker_repo


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


def _sh(script: str) -> subprocess.CompletedProcess:
    return subprocess.run(["sh", "-c", script], capture_output=True, text=True, timeout=60)


def _probe(dest, pin) -> aptrepo.InstalledKey:
    return aptrepo.installed_key(_sh(aptrepo.key_probe(str(dest), pin)).stdout)


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
    proc = _sh(aptrepo.key_script(docker_repo(f"file://{served}", str(dest), fpr, None)))
    assert proc.returncode == 1
    assert proc.stderr.count("\n") == 1, proc.stderr  # one line
    assert f"holds 2 keys ({fpr} {other}); only docker_apt_key_fingerprint {fpr} may be in it; key not installed" in proc.stderr
    assert list(dest.parent.iterdir()) == []


def test_a_poisoned_keyring_on_the_host_is_not_current_and_is_replaced(tmp_path, keys):
    (fpr, key), (other, intruder) = keys
    dest = tmp_path / "keyrings" / "docker.asc"
    dest.parent.mkdir()
    dest.write_bytes(key + intruder)
    dest.chmod(0o644)
    probe = _sh(aptrepo.key_probe(str(dest), fpr)).stdout
    assert aptrepo.installed_key(probe) == aptrepo.InstalledKey((fpr, other), canonical=False)
    assert not aptrepo.key_is_current(docker_repo("", str(dest), fpr, None), _snap(dest, probe))
    assert aptrepo.key_is_current(docker_repo("", str(dest), fpr, None), _snap(dest, f"{fpr}\n{aptrepo.CANONICAL}\n"))
    served = tmp_path / "gpg"
    served.write_bytes(key)
    proc = _sh(aptrepo.key_script(docker_repo(f"file://{served}", str(dest), fpr, None)))
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
    proc = _sh(aptrepo.key_script(docker_repo(f"file://{served}", str(dest), fpr, None)))
    assert proc.returncode == 1 and "key not installed" in proc.stderr
    assert list(dest.parent.iterdir()) == []


def test_a_single_good_key_is_kept_when_the_download_is_refused(tmp_path, keys):
    (fpr, key), (_, intruder) = keys
    dest = tmp_path / "keyrings" / "docker.asc"
    dest.parent.mkdir()
    dest.write_bytes(key)
    served = tmp_path / "gpg"
    served.write_bytes(key + intruder)
    assert _sh(aptrepo.key_script(docker_repo(f"file://{served}", str(dest), fpr, None))).returncode == 1
    assert dest.read_bytes() == key


def _nvidia_repo(url: str, key_path: str, fingerprint: str) -> aptrepo.Repository:
    """NVIDIA's repository as the gpu role declares it (no sha256 setting)."""
    from roles import gpu
    from tests.unit.harness import merged

    data = merged("robots", {"gpu": "nvidia", "gpu_apt_key_url": url, "gpu_apt_key_path": key_path,
                             "gpu_apt_key_fingerprint": fingerprint})
    return gpu.repository(data, "amd64")


@pytest.mark.parametrize("payload", ["$(touch${IFS}%s)", "`touch${IFS}%s`", "\"$(touch${IFS}%s)\""])
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
    repos = [docker_repo(url, str(dest), fingerprint, sha256)
             for fingerprint, sha256 in (("DEAD" * 10, None), (None, "0" * 64), (fpr, "0" * 64))]
    repos += [_nvidia_repo(url, str(dest), "DEAD" * 10), _nvidia_repo(missing, str(dest), fpr),
              docker_repo(missing, str(dest), fpr)]
    for repo in repos:
        proc = _sh(aptrepo.key_script(repo))
        assert proc.returncode == 1, proc.stderr
        assert repo.key_url in proc.stderr and ("key not installed" in proc.stderr or "cannot download" in proc.stderr)
        assert not pwned.exists(), f"the URL ran as a command: {proc.stderr}"
    assert not dest.exists()


# --- compose: values reach the container verbatim (issue 8 item 4) ---------

def test_every_string_written_to_compose_has_its_dollars_escaped():
    import yaml

    from roles.payload import compose
    from tests.unit.harness import merged

    data = merged("robots", {
        "payload_image": "reg.lan/ros/payload:1.0",
        "payload_environment": {"PASSWORD": "s3cr$et", "REQUIRED": "${X:?}", "PLAIN": "a$$b"},
        "payload_command": ["sh", "-c", "echo $HOME"],
        "payload_volumes": ["/srv/$data:/data"],
    })
    doc = yaml.safe_load(compose.dump(desired_compose(data, "10.0.0.1")))
    service = doc["services"]["payload"]
    assert service["environment"]["PASSWORD"] == "s3cr$$et"
    assert service["environment"]["REQUIRED"] == "$${X:?}"
    assert service["environment"]["PLAIN"] == "a$$$$b"
    assert service["command"] == ["sh", "-c", "echo $$HOME"]
    assert service["volumes"] == ["/srv/$$data:/data"]
    assert service["image"] == "reg.lan/ros/payload:1.0"


# --- symlinks where a managed file or directory is wanted (items 7, 8) ------

def test_the_snapshot_reports_a_symlink_as_a_link(tmp_path):
    (tmp_path / "target").write_text("{}\n")
    (tmp_path / "dir").mkdir()
    for name, target in (("to-file", "target"), ("to-dir", "dir"), ("dangling", "nowhere")):
        (tmp_path / name).symlink_to(tmp_path / target)
    paths = [str(tmp_path / n) for n in ("to-file", "to-dir", "dangling", "target", "dir")]
    fact = HostSnapshot()
    out = subprocess.run(["sh", "-c", fact.command(files=paths)], capture_output=True, text=True, check=True)
    snap = fact.process(out.stdout.splitlines())
    kinds = {p.rsplit("/", 1)[1]: (snap.files[p].kind if snap.files[p] else None) for p in paths}
    assert kinds == {"to-file": "link", "to-dir": "link", "dangling": "link", "target": "file", "dir": "dir"}


@pytest.mark.parametrize("target_kind", ["file", "dir"])
def test_writing_a_file_replaces_a_symlink_and_leaves_its_target_alone(tmp_path, target_kind):
    import grp
    import os
    import pwd

    from robotfleet.host import operations

    target = tmp_path / "elsewhere"
    if target_kind == "file":
        target.write_text("not yours\n")
    else:
        target.mkdir()
    dest = tmp_path / "etc" / "daemon.json"
    dest.parent.mkdir()
    dest.symlink_to(target)
    user, group = pwd.getpwuid(os.getuid()).pw_name, grp.getgrgid(os.getgid()).gr_name
    command = operations.write_file_command(str(dest), b"{}\n", "0644", user, group)
    stdin = "\n".join(command.connector_arguments["_stdin"]) + "\n"
    proc = subprocess.run(command.get_raw_value(), shell=True, input=stdin, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert not dest.is_symlink() and dest.read_bytes() == b"{}\n"
    if target_kind == "file":
        assert target.read_text() == "not yours\n"
    else:
        assert list(target.iterdir()) == []


def test_a_symlinked_daemon_json_is_replaced_by_a_file_and_docker_restarts():
    from robotfleet.host.snapshot import FileState
    from tests.unit.harness import find, plan
    from tests.unit.harness import ROBOT, converged

    snap = converged("robots", ROBOT, "debian-13")
    snap.files["/etc/docker/daemon.json"] = FileState("link", None, "777", "root", "root")
    result = plan({"r1": ("robots", ROBOT, snap)})
    assert result.failed == set()
    commands = result["r1"]
    assert len(find(commands, r"dest=/etc/docker/daemon.json\n")) == 1
    assert not find(commands, "chown root:root /etc/docker/daemon.json")
    assert find(commands, "systemctl restart docker.service")


def test_a_symlinked_directory_is_refused_with_one_line(tmp_path):
    from robotfleet.host.snapshot import FileState
    from tests.unit.harness import find, plan
    from tests.unit.harness import ROBOT, converged

    snap = converged("robots", ROBOT, "debian-13")
    snap.files["/etc/docker"] = FileState("link", None, "777", "root", "root")
    result = plan({"r1": ("robots", ROBOT, snap)})
    assert result.failed == {"r1"}
    refusal = find(result["r1"], "symbolic link")
    assert len(refusal) == 1 and "/etc/docker is a symbolic link; not following it" in refusal[0]
    assert not find(result["r1"], "install -d")


def test_the_directory_command_itself_refuses_a_symlink(tmp_path):
    """The snapshot is a moment ago: the command checks again before install -d/chmod."""
    from robotfleet.host import operations

    real = tmp_path / "real"
    real.mkdir(mode=0o1777)
    real.chmod(0o1777)
    link = tmp_path / "link"
    link.symlink_to(real)
    command = operations.directory_command(str(link), "0755", "root", "root")
    proc = subprocess.run(command.get_raw_value(), shell=True, capture_output=True, text=True)
    assert proc.returncode == 1 and "is a symbolic link" in proc.stderr
    assert oct(real.stat().st_mode)[-4:] == "1777"


# --- registry login decided by a hash of the credentials (item 9) ----------

SECRET = "pa55-w0rd-never-shown"


def _login_plan(monkeypatch, probe: str | None, image: str = "reg.example.com/ros/payload:1.0", password=SECRET):
    from tests.unit.harness import plan
    from tests.unit.harness import ROBOT, converged

    monkeypatch.setenv("PAYLOAD_REGISTRY_USERNAME", "puller")
    monkeypatch.setenv("PAYLOAD_REGISTRY_PASSWORD", password)
    data = {**ROBOT, "payload_image": image}
    snap = converged("robots", data, "debian-13")
    if probe is not None:
        snap.probes["registry_auth"] = probe
    result = plan({"r1": ("robots", data, snap)})
    assert result.failed == set()
    return [c for c in result["r1"] if "docker login" in c]


def test_docker_hub_logins_are_looked_up_under_the_key_docker_stores_them_at():
    from roles.payload import login

    for registry in ("docker.io", "index.docker.io", "registry-1.docker.io"):
        assert login.registry_config_key(registry) == "https://index.docker.io/v1/"
        assert '"https://index.docker.io/v1/"' in login.registry_probe(registry)
    assert login.registry_config_key("reg.lan:5000") == "reg.lan:5000"


def test_login_runs_when_never_logged_in_and_the_secret_is_not_in_the_command(monkeypatch):
    logins = _login_plan(monkeypatch, probe="")
    assert len(logins) == 1
    assert SECRET not in logins[0]
    assert "--password-stdin" in logins[0] and "read -r record" in logins[0]


def test_same_credentials_plan_no_login_and_a_changed_password_logs_in_again(monkeypatch):
    from roles.payload import login

    record = login.credentials_record("reg.example.com", "puller", SECRET, salt="00" * 16)
    assert SECRET not in record and "puller" not in record
    assert _login_plan(monkeypatch, probe=record + "\n") == []
    assert len(_login_plan(monkeypatch, probe=record + "\n", password=SECRET + "-rotated")) == 1
    # a record for another registry does not count
    other = login.credentials_record("other.example.com", "puller", SECRET, salt="00" * 16)
    assert len(_login_plan(monkeypatch, probe=other + "\n")) == 1


def test_an_old_style_yes_from_the_probe_is_not_taken_as_logged_in(monkeypatch):
    assert len(_login_plan(monkeypatch, probe="yes\n")) == 1


# --- push: the image goes over the command's stdin, no path on the robot (item 6)

def test_the_pushed_archive_goes_over_stdin_intact_through_pyinfras_writer(tmp_path):
    """pyinfra's own write_stdin sends it, a real base64 -d reads it back."""
    import os

    from pyinfra.connectors.util import write_stdin

    from roles.payload import push

    archive = tmp_path / "image.tar"
    archive.write_bytes(os.urandom(3 * push.ArchiveStdin.CHUNK + 12345))
    command = push.load_command(str(archive), "/var/lib/robot-payload", "reg.lan/ros/payload:1.0", "sha256:a", {})
    raw = command.get_raw_value()
    assert "base64 -d | docker load" in raw
    assert "/tmp" not in raw and "robotprov-image" not in raw and "-i " not in raw
    stdin = command.connector_arguments["_stdin"]
    assert stdin  # pyinfra only writes a truthy stdin
    received = tmp_path / "received"
    with open(received, "wb") as sink:
        proc = subprocess.Popen(["base64", "-d"], stdin=subprocess.PIPE, stdout=sink)
        write_stdin(stdin, proc.stdin)
        assert proc.wait(timeout=60) == 0
    assert received.read_bytes() == archive.read_bytes()
    # sent twice (sudo password retry): the same bytes again
    assert "".join(stdin) == "".join(stdin)



def test_the_archive_sent_is_gzip_compressed_and_smaller_than_the_layers(tmp_path):
    """base64 costs a third more on the wire; docker save layers are plain
    tar, so the archive is gzipped (docker load reads gzip as it is)."""
    import gzip
    import io
    import json
    import os
    import tarfile

    from roles.payload import push

    saved = tmp_path / "saved.tar"
    layer = (b"robot payload layer " * 4000) + os.urandom(2000)
    with tarfile.open(saved, "w") as tar:
        for name, data in (("cfg.json", json.dumps({"rootfs": {"diff_ids": ["sha256:a"]}}).encode()),
                           ("l1/layer.tar", layer),
                           ("manifest.json", json.dumps([{"Config": "cfg.json", "Layers": ["l1/layer.tar"]}]).encode())):
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
    out = tmp_path / "sent"
    report = push.strip_layers(str(saved), str(out), [])
    assert out.read_bytes()[:2] == b"\x1f\x8b"
    with tarfile.open(fileobj=io.BytesIO(gzip.decompress(out.read_bytes()))) as sent:
        assert sent.extractfile("l1/layer.tar").read() == layer
    assert report["sent"] * 4 / 3 < report["full"]


# --- daemon.json may hold proxy credentials: root's alone (issue 27, item 7) ---

def test_daemon_json_and_its_previous_copy_are_written_0600_whatever_the_old_mode(tmp_path):
    """The write script runs for real (sh, this machine's dockerd): an old
    0644 daemon.json holding a proxy password is kept as .previous 0600 (not
    copied with its mode), and the new file is 0600 too."""
    import base64
    import os
    import stat

    from roles.docker import daemon

    dest, previous, pending = tmp_path / "daemon.json", tmp_path / "daemon.json.previous", tmp_path / "daemon.json.pending"
    old = '{"proxies": {"http-proxy": "http://u:s3cret@proxy:3128"}}\n'
    dest.write_text(old)
    os.chmod(dest, 0o644)
    new = base64.encodebytes(b'{"live-restore": true}\n').decode()
    proc = subprocess.run(["sh", "-c", daemon.write_script(str(dest), str(previous), str(pending))],
                          input=new, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert dest.read_text() == '{"live-restore": true}\n' and previous.read_text() == old
    for path in (dest, previous):
        info = path.stat()
        assert (stat.S_IMODE(info.st_mode), info.st_uid, info.st_gid) == (0o600, 0, 0), path
