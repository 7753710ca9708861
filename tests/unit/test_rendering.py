"""Every generated file: compose, unit, udev rules, daemon.json, docker.sources.
The generated scripts run for real by sh in tests/integration/test_rendering.py."""

import json

import yaml

from roles import x11
from roles.docker import plan as docker_plan
from roles.payload import compose, installed_files
from roles.udev import rules
from tests.unit.harness import desired_compose, merged, release_spec

SENSORS = [
    {
        "name": "front_camera",
        "subsystem": "video4linux",
        "vendor_id": "046D",
        "product_id": "0825",
        "usb_port": "1-1.2",
    },
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
    text = docker_plan.daemon_json(
        data["docker_daemon_options"], {"registry-mirrors": ["https://m.lan"], "insecure-registries": ["lab:5000"]}
    )
    assert text.endswith("}\n")
    parsed = json.loads(text)
    assert parsed["live-restore"] is True
    assert parsed["log-opts"] == {"max-file": "3", "max-size": "10m"}
    assert parsed["registry-mirrors"] == ["https://m.lan"] and parsed["insecure-registries"] == ["lab:5000"]
    assert list(parsed) == sorted(parsed)
    assert docker_plan.daemon_json({"insecure-registries": ["a"]}, {"insecure-registries": ["a", "b"]}) == (
        '{\n  "insecure-registries": [\n    "a",\n    "b"\n  ]\n}\n'
    )


def test_compose_for_a_robot():
    data = merged(
        "robots",
        {
            "payload_image": "reg.lan/ros/payload:1.0",
            "udev_sensors": SENSORS,
            "ros_domain_id": 7,
            "payload_environment": {"DEBUG": True, "RATE": 10},
            "payload_volumes": ["/var/lib/maps:/maps"],
        },
    )
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
    data = merged(
        "laptops",
        {
            "payload_image": "reg.lan/ros/payload:1.0",
            "x11_user": "alice",
            "ros_domain_id": 0,
            "ros_master_uri": "http://master:11311",
            "payload_gpu": True,
        },
    )
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
    """The release's identity, as the deploy hands it to payloadctl: how an
    update is carried out (timeouts, delivery, lock) is in the spec but not
    in the hash, so changing it releases nothing; what runs changes it."""
    base = {"payload_image": "r.lan/p:1.0"}

    def spec(**settings):
        data = merged("robots", {**base, **settings})
        return release_spec(data, desired_compose(data, "h"))

    one = spec()
    how = {
        "payload_health_timeout": 300,
        "payload_stable_seconds": 0,
        "payload_pull_timeout": 60,
        "payload_apply_lock_timeout": 10,
        "payload_keep_releases": 5,
        "payload_delivery": "push",
        "payload_update_lock_path": "/run/elsewhere/update.lock",
    }
    for name, value in how.items():
        other = spec(**{name: value})
        assert other.to_dict() != one.to_dict(), name  # the setting does reach the spec ...
        assert other.spec_hash == one.spec_hash, name  # ... but not the release's identity
    what = {
        "payload_image": "r.lan/p:1.1",
        "payload_environment": {"RATE": "10"},
        "payload_volumes": ["/var/lib/maps:/maps"],
        "payload_autostart": False,
        "ros_domain_id": 7,
    }
    for name, value in what.items():
        assert spec(**{name: value}).spec_hash != one.spec_hash, name
    doc = desired_compose(merged("robots", base), "h")
    reordered = {key: doc[key] for key in reversed(list(doc))}
    assert list(reordered) != list(doc) and compose.spec_hash(reordered, True) == compose.spec_hash(doc, True)


def test_unit_never_removes_volumes_and_waits_only_for_devices_it_has():
    """Its full text is in tests/unit/golden/ and checked by systemd-analyze
    (test_generated_files.py); here only what a golden copy cannot say."""
    data = merged("robots", {"payload_image": "r.lan/p:1.0"})
    text = installed_files.unit_text(data, ["/dev/robot/lidar"])
    lines = text.splitlines()
    # A Docker restart must not stop the payload: ordering and a weak dependency only.
    assert not [line for line in lines if line.startswith(("Requires=", "BindsTo=", "PartOf="))]
    assert "Wants=docker.service network-online.target" in lines
    # Boot goes through payloadctl, which undoes a release a power cut left unverified.
    assert any(
        line.startswith("ExecStart=/usr/bin/python3 /usr/local/lib/robot-payload/payloadctl start ") for line in lines
    )
    assert " -v" not in text
    assert "ExecStartPre" not in installed_files.unit_text(data, [])


def test_x11_cookie_script_uses_the_family_wild_method():
    data = merged("laptops", {"x11_user": "alice"})
    script = x11.cookie_script(data)
    assert 'xauth nlist "$DISPLAY" | sed -e \'s/^..../ffff/\' | xauth -q -f "$tmp" nmerge -' in script
    assert 'dir="/var/lib/robot-x11/$(id -un)"' in script and "umask 077" in script
    assert "xhost" not in script.replace("`xhost +`", "")
