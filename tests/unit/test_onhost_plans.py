"""Issue 8, the planned half: what the roles plan for values that could
escape into compose, for symlinks where a managed file is wanted, for
registry logins and for a pushed image.  The generated shell scripts run for
real (sh, gpg, curl on file:// URLs) in tests/integration/test_onhost_security.py."""

from __future__ import annotations

import gzip
import io
import json
import os
import tarfile

import yaml

from robotfleet.host.snapshot import FileState
from roles.payload import compose, image_transfer, login
from tests.unit.harness import ROBOT, converged, desired_compose, find, merged, plan


def test_every_string_written_to_compose_has_its_dollars_escaped():
    data = merged(
        "robots",
        {
            "payload_image": "reg.lan/ros/payload:1.0",
            "payload_environment": {"PASSWORD": "s3cr$et", "REQUIRED": "${X:?}", "PLAIN": "a$$b"},
            "payload_command": ["sh", "-c", "echo $HOME"],
            "payload_volumes": ["/srv/$data:/data"],
        },
    )
    doc = yaml.safe_load(compose.dump(desired_compose(data, "10.0.0.1")))
    service = doc["services"]["payload"]
    assert service["environment"]["PASSWORD"] == "s3cr$$et"
    assert service["environment"]["REQUIRED"] == "$${X:?}"
    assert service["environment"]["PLAIN"] == "a$$$$b"
    assert service["command"] == ["sh", "-c", "echo $$HOME"]
    assert service["volumes"] == ["/srv/$$data:/data"]
    assert service["image"] == "reg.lan/ros/payload:1.0"


def test_a_symlinked_daemon_json_is_replaced_by_a_file_and_docker_restarts():
    snap = converged("robots", ROBOT, "debian-13")
    snap.files["/etc/docker/daemon.json"] = FileState("link", None, "777", "root", "root")
    result = plan({"r1": ("robots", ROBOT, snap)})
    assert result.failed == set()
    commands = result["r1"]
    assert len(find(commands, r"dest=/etc/docker/daemon.json\n")) == 1
    assert not find(commands, "chown root:root /etc/docker/daemon.json")
    assert find(commands, "systemctl restart docker.service")


def test_a_symlinked_directory_is_refused_with_one_line(tmp_path):
    snap = converged("robots", ROBOT, "debian-13")
    snap.files["/etc/docker"] = FileState("link", None, "777", "root", "root")
    result = plan({"r1": ("robots", ROBOT, snap)})
    assert result.failed == {"r1"}
    refusal = find(result["r1"], "symbolic link")
    assert len(refusal) == 1 and "/etc/docker is a symbolic link; not following it" in refusal[0]
    assert not find(result["r1"], "install -d")


SECRET = "pa55-w0rd-never-shown"


def _login_plan(monkeypatch, probe: str | None, image: str = "reg.example.com/ros/payload:1.0", password=SECRET):
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
    record = login.credentials_record("reg.example.com", "puller", SECRET, salt="00" * 16)
    assert SECRET not in record and "puller" not in record
    assert _login_plan(monkeypatch, probe=record + "\n") == []
    assert len(_login_plan(monkeypatch, probe=record + "\n", password=SECRET + "-rotated")) == 1
    # a record for another registry does not count
    other = login.credentials_record("other.example.com", "puller", SECRET, salt="00" * 16)
    assert len(_login_plan(monkeypatch, probe=other + "\n")) == 1


def test_an_old_style_yes_from_the_probe_is_not_taken_as_logged_in(monkeypatch):
    assert len(_login_plan(monkeypatch, probe="yes\n")) == 1


def test_the_archive_sent_is_gzip_compressed_and_smaller_than_the_layers(tmp_path):
    """base64 costs a third more on the wire; docker save layers are plain
    tar, so the archive is gzipped (docker load reads gzip as it is)."""
    saved = tmp_path / "saved.tar"
    layer = (b"robot payload layer " * 4000) + os.urandom(2000)
    with tarfile.open(saved, "w") as tar:
        for name, data in (
            ("cfg.json", json.dumps({"rootfs": {"diff_ids": ["sha256:a"]}}).encode()),
            ("l1/layer.tar", layer),
            ("manifest.json", json.dumps([{"Config": "cfg.json", "Layers": ["l1/layer.tar"]}]).encode()),
        ):
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
    out = tmp_path / "sent"
    report = image_transfer.strip_layers(str(saved), str(out), [])
    assert out.read_bytes()[:2] == b"\x1f\x8b"
    with tarfile.open(fileobj=io.BytesIO(gzip.decompress(out.read_bytes()))) as sent:
        assert sent.extractfile("l1/layer.tar").read() == layer
    assert report["sent"] * 4 / 3 < report["full"]
