"""Every generated file: compose, unit, udev rules, daemon.json, docker.sources,
and the snapshot script run for real by sh on this machine."""

import json
import re
import subprocess

import yaml

from robotfleet.host import aptrepo
from robotfleet.host import snapshot as hoststate
from robotfleet.host import snapshot_sh
from roles import x11
from roles.docker import plan as docker_plan
from roles.payload import compose, robot
from roles.udev import rules
from tests import armor
from tests.unit.harness import desired_compose, docker_repo, merged

SENSORS = [
    {"name": "front_camera", "subsystem": "video4linux", "vendor_id": "046D", "product_id": "0825", "usb_port": "1-1.2"},
    {"name": "back_camera", "subsystem": "video4linux", "vendor_id": "046d", "product_id": "0825", "usb_port": "1-1.3"},
    {"name": "lidar", "subsystem": "tty", "serial": "0001A2B3", "group": "plugdev", "mode": "640"},
    {"name": "debug", "subsystem": "tty", "serial": "X", "passthrough": False, "symlink": "robot/dbg/uart"},
]


def test_udev_rules_give_identical_cameras_names_by_port():
    text = rules.render(SENSORS)
    lines = [line for line in text.splitlines() if line and not line.startswith("#")]
    assert lines[0] == (
        'ACTION!="remove", SUBSYSTEM=="video4linux", ATTR{index}=="0", KERNELS=="1-1.2", '
        'ATTRS{idVendor}=="046d", ATTRS{idProduct}=="0825", SYMLINK+="robot/front_camera", GROUP="video", MODE="0660"'
    )
    assert 'KERNELS=="1-1.3"' in lines[1] and 'SYMLINK+="robot/back_camera"' in lines[1]
    assert lines[2] == (
        'ACTION!="remove", SUBSYSTEM=="tty", ATTRS{serial}=="0001A2B3", SYMLINK+="robot/lidar", '
        'GROUP="plugdev", MODE="0640"'
    )
    assert rules.lint(text) == []
    assert rules.subsystems(text) == {"video4linux", "tty"}
    assert rules.devices(SENSORS) == ["/dev/robot/front_camera", "/dev/robot/back_camera", "/dev/robot/lidar"]


def test_udev_lint_catches_broken_and_world_writable_rules():
    assert rules.lint('KERNEL=="ttyUSB0", SYMLINK+="x"\n') == []
    assert rules.lint('KERNEL=="ttyUSB0" SYMLINK+="x"\n') != []
    assert rules.lint('KERNEL=="ttyUSB0", SYMLNK+="x"\n') == ["line 1: unknown key SYMLNK"]
    assert rules.lint('KERNEL=="tty*", MODE="0666"\n') == ["line 1: MODE 0666 is world-writable"]
    assert rules.lint('KERNEL=="tty*", MODE="0666"\n', allow_world_writable=True) == []
    assert rules.lint('KERNEL=="tty*" MODE="0666"\n', allow_world_writable=True) != []
    assert rules.lint('KERNEL=="a", \\\n  SYMLINK+="b"\n') == []


def test_shipped_vendor_rules_pass_the_lint():
    from roles.udev import VENDOR_RULES_DIR
    files = sorted(VENDOR_RULES_DIR.glob("*.rules"))
    assert files
    for path in files:
        assert rules.lint(path.read_text()) == [], path


def test_daemon_json_sorted_with_robot_defaults_and_registries():
    data = merged("robots", {})
    text = docker_plan.daemon_json(data["docker_daemon_options"], ["https://m.lan"], ["lab:5000"])
    assert text.endswith("}\n")
    parsed = json.loads(text)
    assert parsed["live-restore"] is True
    assert parsed["log-opts"] == {"max-file": "3", "max-size": "10m"}
    assert parsed["registry-mirrors"] == ["https://m.lan"] and parsed["insecure-registries"] == ["lab:5000"]
    assert list(parsed) == sorted(parsed)
    assert docker_plan.daemon_json({"insecure-registries": ["a"]}, [], ["a", "b"]) == (
        '{\n  "insecure-registries": [\n    "a",\n    "b"\n  ]\n}\n'
    )


def test_compose_for_a_robot():
    data = merged("robots", {
        "payload_image": "reg.lan/ros/payload:1.0", "sensors": SENSORS, "ros_domain_id": 7,
        "payload_environment": {"DEBUG": True, "RATE": 10}, "payload_volumes": ["/var/lib/maps:/maps"],
    })
    doc = yaml.safe_load(compose.dump(desired_compose(data, "10.0.0.1")))
    service = doc["services"]["payload"]
    assert doc["name"] == "robot-payload"
    assert service["image"] == "reg.lan/ros/payload:1.0"
    assert service["network_mode"] == "host" and service["restart"] == "unless-stopped"
    assert service["environment"] == {"ROS_DOMAIN_ID": "7", "DEBUG": "true", "RATE": "10"}
    assert service["devices"] == [
        "/dev/robot/front_camera:/dev/robot/front_camera",
        "/dev/robot/back_camera:/dev/robot/back_camera",
        "/dev/robot/lidar:/dev/robot/lidar",
    ]
    assert service["volumes"] == ["/var/lib/maps:/maps"]
    assert "deploy" not in service and "DISPLAY" not in service["environment"]


def test_compose_ros1_x11_and_gpu():
    data = merged("laptops", {
        "payload_image": "reg.lan/ros/payload:1.0", "x11_user": "alice", "ros_domain_id": 0,
        "ros_master_uri": "http://master:11311", "payload_gpu": True,
    })
    service = desired_compose(data, "10.0.0.5")["services"]["payload"]
    env = service["environment"]
    assert env["ROS_MASTER_URI"] == "http://master:11311" and env["ROS_HOSTNAME"] == "10.0.0.5"
    assert "ROS_DOMAIN_ID" not in env
    assert env["DISPLAY"] == ":0" and env["XAUTHORITY"] == "/tmp/.robot-x11/Xauthority"
    assert service["volumes"] == ["/tmp/.X11-unix:/tmp/.X11-unix:ro", "/var/lib/robot-x11/alice:/tmp/.robot-x11:ro"]
    assert service["deploy"]["resources"]["reservations"]["devices"] == [
        {"driver": "nvidia", "count": "all", "capabilities": ["gpu"]}
    ]


def test_spec_hash_changes_with_what_runs_only():
    data = merged("robots", {"payload_image": "r.lan/p:1.0"})
    one = desired_compose(data, "h")
    two = desired_compose(merged("robots", {"payload_image": "r.lan/p:1.1"}), "h")
    assert compose.spec_hash(one, True) == compose.spec_hash(desired_compose(data, "h"), True)
    assert compose.spec_hash(one, True) != compose.spec_hash(two, True)
    assert compose.spec_hash(one, True) != compose.spec_hash(one, False)


def test_unit_never_removes_volumes_and_waits_only_for_devices_it_has():
    """Its full text is in tests/unit/golden/ and checked by systemd-analyze
    (test_generated_files.py); here only what a golden copy cannot say."""
    data = merged("robots", {"payload_image": "r.lan/p:1.0"})
    text = robot.unit_text(data, ["/dev/robot/lidar"])
    lines = text.splitlines()
    # A Docker restart must not stop the payload: ordering and a weak dependency only.
    assert not [line for line in lines if line.startswith(("Requires=", "BindsTo=", "PartOf="))]
    assert "Wants=docker.service network-online.target" in lines
    # Boot goes through payloadctl, which undoes a release a power cut left unverified.
    assert any(line.startswith("ExecStart=/usr/bin/python3 /usr/local/lib/robot-payload/payloadctl start ") for line in lines)
    assert " -v" not in text
    assert "ExecStartPre" not in robot.unit_text(data, [])


def test_x11_cookie_script_uses_the_family_wild_method():
    data = merged("laptops", {"x11_user": "alice"})
    script = x11.cookie_script(data)
    assert "xauth nlist \"$DISPLAY\" | sed -e 's/^..../ffff/' | xauth -q -f \"$tmp\" nmerge -" in script
    assert 'dir="/var/lib/robot-x11/$(id -un)"' in script and "umask 077" in script
    assert "xhost" not in script.replace("`xhost +`", "")
    proc = subprocess.run(["sh", "-n"], input=script, text=True, capture_output=True)
    assert proc.returncode == 0, proc.stderr


def test_snapshot_script_runs_on_a_real_shell(tmp_path):
    (tmp_path / "f").write_text("hello\n")
    (tmp_path / "f").chmod(0o640)
    (tmp_path / "d").mkdir()
    query = dict(
        files=[str(tmp_path / "f"), str(tmp_path / "d"), str(tmp_path / "missing file")],
        packages=["dpkg", "surely-not-a-package"],
        users=["root", "surely-not-a-user"],
        commands=["sh", "surely-not-a-command"],
        probes={"two lines": "echo a; echo 'b c'", "fails": "false"},
    )
    out = subprocess.run(["sh", "-c", hoststate.snapshot_script(**query)], capture_output=True, text=True, check=True)
    snap = hoststate.parse(out.stdout.splitlines(), query)
    assert snap.os_release.get("id") in ("debian", "ubuntu")
    assert snap.arch
    assert "dpkg" in snap.packages and "surely-not-a-package" not in snap.packages
    f = snap.files[str(tmp_path / "f")]
    assert f.kind == "file" and f.mode == "640" and f.sha256 == "5891b5b522d5df086d0ff0b110fbd9d21bb4fc7163af34d08286a2e846f6be03"
    assert snap.files[str(tmp_path / "d")].kind == "dir"
    assert snap.files[str(tmp_path / "missing file")] is None
    assert "root" in snap.users["root"] and snap.users["surely-not-a-user"] is None
    assert snap.commands["sh"] and snap.commands["surely-not-a-command"] is None
    assert snap.probes["two lines"] == "a\nb c\n" and snap.probes["fails"] == ""


def _all_kinds_of_paths(tmp_path) -> list[str]:
    import os

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
        out = subprocess.run(["sh", "-c", hoststate.snapshot_script(**query)], capture_output=True, text=True, check=True)
        snap = hoststate.parse(out.stdout.splitlines(), query)
        return {path: snap.files[path] for path in paths}, out.stdout

    batched, text = files()
    assert "\nstat\t" in "\n" + text and "\nfile\t" not in "\n" + text
    monkeypatch.setattr(snapshot_sh, "PLAIN_PATH", re.compile(r"(?!)"))  # every path on its own
    one_by_one, text = files()
    assert "\nfile\t" in "\n" + text
    assert batched == one_by_one
    kinds = {path.rsplit("/", 1)[1]: state and (state.kind, state.sha256) for path, state in batched.items()}
    assert kinds == {"f": ("file", "5891b5b522d5df086d0ff0b110fbd9d21bb4fc7163af34d08286a2e846f6be03"),
                     "empty": ("file", "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855"),
                     "d": ("dir", None), "link": ("link", None), "fifo": None, "missing": None}


def test_snapshot_runs_its_slow_reads_one_after_another_without_a_temporary_directory(tmp_path):
    import os

    fake = tmp_path / "bin"
    fake.mkdir()
    (fake / "mktemp").write_text("#!/bin/sh\nexit 1\n")
    (fake / "mktemp").chmod(0o755)
    query = dict(probes={"a": "echo a", "b": "echo b"}, packages=["dpkg"])
    env = dict(os.environ, PATH=f"{fake}:{os.environ['PATH']}")
    out = subprocess.run(["sh", "-c", hoststate.snapshot_script(**query)], capture_output=True, text=True, check=True, env=env)
    snap = hoststate.parse(out.stdout.splitlines(), query)
    assert snap.probes["a"] == "a\n" and snap.probes["b"] == "b\n" and "dpkg" in snap.packages


def test_key_download_verifies_before_moving_into_place(tmp_path):
    """Run the real download script against a local file:// key with a wrong pin."""
    key = tmp_path / "key.asc"
    key.write_text("not really a key\n")
    dest = tmp_path / "keyrings" / "docker.asc"
    dest.parent.mkdir()
    script = aptrepo.key_script(docker_repo(f"file://{key}", str(dest), None, "0" * 64))
    proc = subprocess.run(["sh", "-c", script], capture_output=True, text=True)
    assert proc.returncode == 1 and "does not match docker_apt_key_sha256" in proc.stderr
    assert list(dest.parent.iterdir()) == []  # nothing half-written left behind
    good = subprocess.run(["sha256sum", str(key)], capture_output=True, text=True).stdout.split()[0]
    proc = subprocess.run(["sh", "-c", aptrepo.key_script(docker_repo(f"file://{key}", str(dest), None, good))], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert dest.read_text() == "not really a key\n" and oct(dest.stat().st_mode)[-3:] == "644"


def test_file_write_is_atomic_and_validated_before_it_lands(tmp_path):
    """The real write command: a failing check leaves the old file untouched."""
    import grp
    import os
    import pwd

    from robotfleet.host import operations

    user, group = pwd.getpwuid(os.getuid()).pw_name, grp.getgrgid(os.getgid()).gr_name
    dest = tmp_path / "etc" / "x.conf"

    def run(content, validate=None):
        command = operations.write_file_command(str(dest), content, "0640", user, group, validate)
        stdin = "\n".join(command.connector_arguments["_stdin"]) + "\n"
        return subprocess.run(command.get_raw_value(), shell=True, input=stdin, capture_output=True, text=True)

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
    wrong = subprocess.run(["sh", "-c", aptrepo.key_script(docker_repo(url, str(dest), "DEAD" * 10, None))], capture_output=True, text=True)
    assert wrong.returncode == 1 and f"fingerprint {fingerprint} does not match" in wrong.stderr
    assert list(dest.parent.iterdir()) == []
    right = subprocess.run(["sh", "-c", aptrepo.key_script(docker_repo(url, str(dest), fingerprint, None))], capture_output=True, text=True)
    assert right.returncode == 0, right.stderr
    probe = subprocess.run(["sh", "-c", aptrepo.key_probe(str(dest), fingerprint)], capture_output=True, text=True)
    assert aptrepo.installed_key(probe.stdout) == aptrepo.InstalledKey((fingerprint,), canonical=True)


def test_a_stalled_probe_is_cut_off_and_the_snapshot_still_answers(monkeypatch):
    """A wedged dockerd makes `docker ps` hang: one probe must not hang the
    host's only snapshot command (and so every later deploy of that robot)."""
    monkeypatch.setattr(snapshot_sh, "PROBE_TIMEOUT", 1)
    query = dict(probes={"stalls": "sleep 30; echo late", "answers": "echo ok"})
    out = subprocess.run(["sh", "-c", hoststate.snapshot_script(**query)], capture_output=True, text=True,
                         check=True, timeout=20)
    snap = hoststate.parse(out.stdout.splitlines(), query)
    assert snap.probes["stalls"] == "" and snap.probes["answers"] == "ok\n"
