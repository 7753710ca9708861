"""Pure parts of the on-robot release helper (the rest runs end to end)."""

import importlib.util
import json
import subprocess
import sys

import yaml

from roles import payload

spec = importlib.util.spec_from_file_location("payloadctl", payload.HERE / "payloadctl.py")
payloadctl = importlib.util.module_from_spec(spec)
spec.loader.exec_module(payloadctl)


def test_repository_of_references():
    assert payloadctl.repository("reg.lan:5000/ros/payload:1.0") == "reg.lan:5000/ros/payload"
    assert payloadctl.repository("reg.lan:5000/ros/payload@sha256:" + "a" * 64) == "reg.lan:5000/ros/payload"
    assert payloadctl.repository("ros/payload") == "ros/payload"


def test_pinned_prefers_the_digest_of_the_same_repository():
    info = {"id": "sha256:1", "repo_digests": ["other/x@sha256:" + "b" * 64, "reg.lan:5000/ros/payload@sha256:" + "a" * 64]}
    assert payloadctl.pinned("reg.lan:5000/ros/payload:1.0", info) == "reg.lan:5000/ros/payload@sha256:" + "a" * 64
    assert payloadctl.pinned("loaded/only:1.0", {"id": "sha256:1", "repo_digests": []}) == "loaded/only:1.0"


def test_release_pointers_are_swapped_atomically(tmp_path):
    releases = payloadctl.Releases(str(tmp_path))
    for rid, created in (("r1", "2026-01-01T00:00:00Z"), ("r2", "2026-01-02T00:00:00Z")):
        (tmp_path / "releases" / rid).mkdir(parents=True)
        releases.write_record(rid, {"id": rid, "created": created})
    assert releases.pointer("current") is None
    releases.point("current", "r1")
    releases.point("current", "r2")
    releases.point("previous", "r1")
    assert (releases.pointer("current"), releases.pointer("previous")) == ("r2", "r1")
    assert (tmp_path / "current").resolve() == (tmp_path / "releases" / "r2").resolve()
    assert releases.all() == ["r1", "r2"]
    releases.point("previous", None)
    assert releases.pointer("previous") is None


def test_release_compose_is_yaml():
    doc = {"name": "p", "services": {"payload": {"image": "a/b@sha256:" + "c" * 64, "environment": {"A": "1"}}}}
    assert yaml.safe_load(payloadctl.compose_yaml(doc)) == doc


def test_update_lock_holder(tmp_path):
    lock = tmp_path / "update.lock"
    assert payloadctl.update_lock_holder(str(lock)) is None
    lock.write_text("robot is moving\n")
    assert payloadctl.update_lock_holder(str(lock)) == "robot is moving"
    lock.write_text("")
    assert payloadctl.update_lock_holder(str(lock)) == "no reason given"


def test_wait_devices_names_the_missing_sensor(tmp_path):
    present = tmp_path / "cam"
    present.write_text("")
    proc = subprocess.run(
        [sys.executable, str(payload.HERE / "payloadctl.py"), "wait-devices", "--timeout", "1", str(present), str(tmp_path / "lidar")],
        capture_output=True, text=True,
    )
    assert proc.returncode == 1 and proc.stderr.strip().endswith(str(tmp_path / "lidar"))


def test_result_reports_the_last_apply(tmp_path):
    (tmp_path / "last-result.json").write_text(json.dumps({"ok": False, "message": "payload: release x failed"}))
    proc = subprocess.run(
        [sys.executable, str(payload.HERE / "payloadctl.py"), "result", "--dir", str(tmp_path)], capture_output=True, text=True
    )
    assert proc.returncode == 1 and proc.stderr.strip() == "payload: release x failed"


def test_helper_runs_on_python_3_8_syntax():
    import ast

    source = (payload.HERE / "payloadctl.py").read_text()
    ast.parse(source, feature_version=(3, 8))  # Ubuntu 20.04 robots run Python 3.8
    assert "from __future__" not in source


def test_apply_finds_the_release_already_current(tmp_path):
    """A second apply of the same spec (say, after a dropped link) changes nothing."""
    releases = payloadctl.Releases(str(tmp_path))
    (tmp_path / "releases" / "r1").mkdir(parents=True)
    releases.write_record("r1", {"id": "r1", "created": "x", "spec_hash": "abc", "state": "staged"})
    releases.point("current", "r1")
    spec = {"dir": str(tmp_path), "spec_hash": "abc", "autostart": False, "name": "robot-payload",
            "lock_file": str(tmp_path / "lock"), "compose": {"services": {}}, "delivery": "pull"}
    (tmp_path / "spec.json").write_text(json.dumps(spec))
    proc = subprocess.run([sys.executable, str(payload.HERE / "payloadctl.py"), "apply", str(tmp_path / "spec.json")],
                          capture_output=True, text=True)
    assert proc.returncode == 0 and "release r1 is already current" in proc.stdout
    assert sorted(p.name for p in (tmp_path / "releases").iterdir()) == ["r1"]


def _stub_docker(tmp_path, monkeypatch, exec_exit: int):
    """A `docker` on PATH answering `ps` with one container and `exec` with
    ``exec_exit`` (no GPU exists on this machine to run the real check)."""
    stub = tmp_path / "docker"
    stub.write_text(
        "#!/bin/sh\n"
        'echo "$@" >> "$(dirname "$0")/calls"\n'
        'case "$1" in\n'
        "  ps) echo c0ffee ;;\n"
        "  inspect) exit 1 ;;\n"
        f"  exec) echo 'NVIDIA-SMI has failed because it could not communicate with the NVIDIA driver' >&2; exit {exec_exit} ;;\n"
        "esac\n"
    )
    stub.chmod(0o755)
    monkeypatch.setenv("PATH", f"{tmp_path}:" + __import__("os").environ["PATH"])
    return tmp_path / "calls"


def test_gpu_check_fails_a_container_that_cannot_see_a_gpu(tmp_path, monkeypatch):
    calls = _stub_docker(tmp_path, monkeypatch, exec_exit=9)
    ok, why = payloadctl.gpu_check("robot-payload", ["nvidia-smi", "-L"])
    assert not ok and why.startswith("c0ffee cannot see a GPU (nvidia-smi -L failed: NVIDIA-SMI has failed")
    assert "exec c0ffee nvidia-smi -L" in calls.read_text()


def test_gpu_check_passes_and_is_skipped_without_a_command(tmp_path, monkeypatch):
    calls = _stub_docker(tmp_path, monkeypatch, exec_exit=0)
    assert payloadctl.gpu_check("robot-payload", ["nvidia-smi", "-L"]) == (True, "")
    assert payloadctl.gpu_check("robot-payload", None) == (True, "")
    assert calls.read_text().count("exec") == 1
