"""ROS logs bounded (the ROS presets): every node logs to ros_log_dir on the
host, which outlives releases; a timer keeps it under ros_log_max_mb, the
oldest files going first (payloadctl prune-logs)."""

import os

from roles.payload import ros_logs
from roles.payload.payloadctl import cli, logs
from tests.fixtures import robot_fleet as host_with
from tests.unit.harness import ROBOT, converged, fleet_problems, plan
from tests.unit.rosfleet import NODES, ROS1, rendered

ROS = {**ROBOT, "payload_image": None, "payload_services": NODES, **ROS1, "udev_sensors": []}


def test_every_service_logs_to_the_host_directory():
    doc = rendered({"payload_services": NODES, **ROS1, "ros_log_dir": "/var/lib/ros-logs"})
    for service in doc["services"].values():
        assert service["environment"]["ROS_LOG_DIR"] == "/var/log/ros"
        assert "/var/lib/ros-logs:/var/log/ros" in service["volumes"]


def test_without_a_preset_no_log_volume_and_no_timer():
    doc = rendered({"payload_services": NODES})
    assert all("ROS_LOG_DIR" not in s["environment"] and "volumes" not in s for s in doc["services"].values())
    sent = " ".join(str(c) for c in plan({"r1": ("robots", ROBOT, converged("robots", ROBOT, "debian-13"))})["r1"])
    assert "ros-logs" not in sent


def test_a_fresh_robot_gets_the_directory_and_the_timer_and_a_converged_one_nothing():
    snap = converged("robots", ROBOT, "debian-13")  # provisioned before it ran ROS
    sent = "\n".join(str(c) for c in plan({"r1": ("robots", ROS, snap)})["r1"])
    assert "install -d -m 755 -o root -g root /var/log/ros" in sent
    assert "/etc/systemd/system/robot-payload-ros-logs.timer" in sent
    assert "systemctl enable robot-payload-ros-logs.timer && systemctl start robot-payload-ros-logs.timer" in sent
    assert plan({"r1": ("robots", ROS, converged("robots", ROS, "debian-13"))})["r1"] == []


def test_the_timer_prunes_with_the_size_set():
    text = ros_logs.service_text(
        type("D", (), {"ros_log_dir": "/var/log/ros", "ros_log_max_mb": 64, "ros_bag_dir": None})()
    )
    assert "payloadctl prune-logs --dir /var/log/ros --max-mb 64" in text
    args = cli.parser().parse_args(["prune-logs", "--dir", "/var/log/ros", "--max-mb", "64"])
    assert (args.func, args.dir, args.max_mb) == (cli.cmd_prune_logs, "/var/log/ros", 64)


def test_bad_log_settings_get_one_line():
    assert fleet_problems(host_with(payload_image="r.example.com/a:1", ros_log_max_mb=0)) == [
        "robots.yaml: robot3.ros_log_max_mb: expected at least 10, got 0"
    ]
    assert fleet_problems(host_with(payload_image="r.example.com/a:1", ros_log_dir="/tmp/ros")) == [
        "robots.yaml: robot3.ros_log_dir: '/tmp/ros' is in the world-writable /tmp; "
        "use a directory only root can write (e.g. under /var/lib)"
    ]


def _log(path, size, age):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"x" * size)
    os.utime(path, (1_700_000_000 + age, 1_700_000_000 + age))


def test_prune_removes_the_oldest_files_until_the_rest_fit(tmp_path):
    for run, age in (("run-a", 0), ("run-b", 100), ("run-c", 200)):
        _log(tmp_path / run / "talker.log", 400 * 1024, age)
        _log(tmp_path / run / "roslaunch.log", 100 * 1024, age + 1)
    (tmp_path / "latest").symlink_to(tmp_path / "run-a")
    removed, _ = logs.prune(str(tmp_path), 1024 * 1024)
    assert removed == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run-b", "run-c"]  # run-a and its dangling latest gone
    assert (tmp_path / "run-c" / "talker.log").exists() and (tmp_path / "run-b" / "roslaunch.log").exists()
    assert logs.prune(str(tmp_path), 1024 * 1024) == (0, 0)


def test_the_bags_prune_touches_only_bag_files(tmp_path):
    """ros_bag_dir is a directory the user names, maybe one that holds more
    than bags: only the oldest *.bag files go, not the user's other files,
    an empty directory, a dangling link, or the bag being written (.active)."""
    _log(tmp_path / "old_0.bag", 600 * 1024, 0)
    _log(tmp_path / "new_0.bag", 600 * 1024, 200)
    _log(tmp_path / "maps" / "site.pgm", 900 * 1024, -100)
    _log(tmp_path / "run_1.bag.active", 600 * 1024, 300)
    (tmp_path / "empty").mkdir()
    (tmp_path / "gone").symlink_to(tmp_path / "nowhere")
    assert logs.prune(str(tmp_path), 1024 * 1024, ".bag") == (1, 600 * 1024)
    left = sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*"))
    assert left == ["empty", "gone", "maps", "maps/site.pgm", "new_0.bag", "run_1.bag.active"]
