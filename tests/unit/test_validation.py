"""Every kind of bad fleet data gets one clear line naming file, host and
field (pyinfra's own CLI refuses it in tests/integration/test_validation.py)."""

import pytest
import yaml

from tests.fixtures import GOOD_HOST, ROOT
from tests.fixtures import good_robot as robot
from tests.unit import harness as fleet
from tests.unit.harness import fleet_problems


def test_example_fleet_is_valid():
    loaded = fleet.load(ROOT / "inventories" / "robots.yaml")
    assert [name for name, _ in loaded.hosts("robots")] == ["robot1", "robot2", "robot3"]
    assert [name for name, _ in loaded.hosts("laptops")] == ["alice-laptop"]
    robot1 = dict(loaded.hosts("robots"))["robot1"]
    assert robot1["ssh_hostname"] == "10.20.0.11" and "address" not in robot1
    assert robot1["payload_image"].endswith(":1.4.2")  # from all.vars


def test_lab_fleet_file_is_valid():
    text = (ROOT / "inventories" / "lab.yaml").read_text()
    text = text.replace("@registry@", "lab-services:5000").replace("@mirror@", "http://lab-services:8080/linux")
    text = text.replace("@mirror_fingerprint@", "6041F729F901FD0081EF611E646BA420EC7C3788")
    assert fleet_problems(yaml.safe_load(text)) == []


def test_defaults_satisfy_the_schema_and_cover_every_setting():
    defaults = fleet.group_data()
    merged = {**defaults["all"], **defaults["robots"], **defaults["laptops"]}
    assert fleet.registry().check_layer(merged) == []
    missing = set(fleet.setting_checks()) - set(merged) - {"ssh_hostname", "ssh_user", "ssh_key"}
    assert missing == set(), f"settings without a default in group_data/: {missing}"


def test_a_setting_has_one_default_only():
    defaults = fleet.group_data()
    for group in ("robots", "laptops"):
        for key in defaults[group]:
            assert key in defaults["all"], f"{key} is only defaulted in group_data/{group}.py"
    assert not set(defaults["robots"]) & {"docker_users", "payload_image"}


# The docs written by hand: README, docs/ but the generated settings table, each role's README.
GENERATED_DOC = ROOT / "docs" / "reference" / "settings.md"
HAND_WRITTEN = [
    ROOT / "README.md",
    *(ROOT / "roles").glob("*/README.md"),
    *(path for path in (ROOT / "docs").rglob("*.md") if path != GENERATED_DOC),
]


def test_every_setting_is_documented_by_hand():
    """Beyond the generated docs/reference/settings.md: README, the docs it
    links, or a role's own roles/<name>/README.md (everything about a role is
    in its folder)."""
    written = "".join(path.read_text() for path in HAND_WRITTEN)
    undocumented = [k for k in fleet.setting_checks() if f"`{k}`" not in written]
    assert undocumented == []


def test_defaults_are_written_once_in_the_declarations():
    """The hand-written docs link docs/reference/settings.md (generated) instead of
    copying defaults: no table of theirs has a default column."""
    copied = [
        f"{path.relative_to(ROOT)}: {line}"
        for path in HAND_WRITTEN
        for line in path.read_text().splitlines()
        if line.startswith("|") and "default" in (cell.strip().lower() for cell in line.strip("|").split("|"))
    ]
    assert copied == []


@pytest.mark.parametrize(
    "doc, expected",
    [
        (
            robot(udev_sensors=[{"name": "cam", "subsystem": "tty", "serial": 42}]),
            "robots.yaml: robot3.udev_sensors[0].serial: expected a string, got 42; quote it",
        ),
        (
            robot(udev_sensors=[{"name": "cam", "subsystem": "tty"}]),
            "robots.yaml: robot3.udev_sensors[0]: needs a match: serial, vendor_id/product_id or usb_port",
        ),
        (
            robot(udev_sensors=[{"name": "cam", "subsystem": "tty", "serail": "x", "serial": "x"}]),
            "robots.yaml: robot3.udev_sensors[0].serail: unknown sensor field (did you mean 'serial'?)",
        ),
        (
            robot(udev_sensors=[{"name": "cam", "subsystem": "camera", "serial": "x"}]),
            "robots.yaml: robot3.udev_sensors[0].subsystem: expected one of tty, video4linux, hidraw, input, usb, "
            "sound, got 'camera'",
        ),
        (
            robot(udev_sensors=[{"name": "cam", "subsystem": "tty", "vendor_id": "046d"}]),
            "robots.yaml: robot3.udev_sensors[0].product_id: vendor_id and product_id go together",
        ),
        (
            robot(udev_sensors=[{"name": "cam", "subsystem": "tty", "usb_port": "usb2"}]),
            "robots.yaml: robot3.udev_sensors[0].usb_port: expected a USB port path like 1-2.1, got 'usb2'",
        ),
        (
            robot(udev_sensors=[{"name": "cam", "subsystem": "tty", "serial": "a", "mode": "0666"}]),
            "robots.yaml: robot3.udev_sensors[0].mode: 0666 is world-writable; use a group "
            "(or set udev_allow_world_writable)",
        ),
        (
            robot(
                udev_sensors=[
                    {"name": "a", "subsystem": "video4linux", "vendor_id": "046d", "product_id": "0825"},
                    {"name": "b", "subsystem": "video4linux", "vendor_id": "046d", "product_id": "0825"},
                ]
            ),
            "robots.yaml: robot3.udev_sensors[1]: b matches the same devices as a (udev_sensors[0]); "
            "add a serial or usb_port to tell them apart",
        ),
        # Two identical cameras, only one told by its port: the other's rule matches both (issue 54, item 1).
        (
            robot(
                udev_sensors=[
                    {
                        "name": "front_camera",
                        "subsystem": "video4linux",
                        "vendor_id": "046d",
                        "product_id": "0825",
                        "usb_port": "1-1.2",
                    },
                    {"name": "back_camera", "subsystem": "video4linux", "vendor_id": "046d", "product_id": "0825"},
                ]
            ),
            "robots.yaml: robot3.udev_sensors[1]: back_camera also matches the devices of front_camera "
            "(udev_sensors[0]): its match (subsystem, vendor_id, product_id) is a part of the other's; "
            "add a serial or usb_port to tell them apart",
        ),
        (
            robot(
                udev_sensors=[
                    {"name": "gps", "subsystem": "tty", "usb_port": "1-1.3"},
                    {"name": "lidar", "subsystem": "tty", "serial": "0001A2B3", "usb_port": "1-1.3"},
                ]
            ),
            "robots.yaml: robot3.udev_sensors[1]: gps (udev_sensors[0]) also matches the devices of lidar: "
            "its match (subsystem, usb_port) is a part of the other's; add a serial or usb_port to tell them apart",
        ),
        (
            robot(
                udev_sensors=[
                    {"name": "a", "subsystem": "tty", "serial": "1"},
                    {"name": "a", "subsystem": "tty", "serial": "2"},
                ]
            ),
            "robots.yaml: robot3.udev_sensors[1].name: duplicate sensor name 'a' (also udev_sensors[0])",
        ),
        (
            robot(udev_sensors=[{"name": "a", "subsystem": "tty", "serial": '1", RUN+="/bin/sh'}]),
            "robots.yaml: robot3.udev_sensors[0].serial: expected a serial of letters, digits and . _ : / + -, "
            "got '1\", RUN+=\"/bin/sh'",
        ),
        (
            robot(payload_image="reg.example.com/ros/payload"),
            "robots.yaml: robot3.payload_image: 'reg.example.com/ros/payload' has no tag or digest; "
            "pin a version (e.g. reg.example.com/ros/payload:1.4.2 or @sha256:...)",
        ),
        (
            robot(payload_image="reg.example.com/ros/payload:latest"),
            "robots.yaml: robot3.payload_image: 'reg.example.com/ros/payload:latest' uses the moving tag 'latest'; "
            "pin a version or digest (or set payload_allow_latest: true)",
        ),
        (
            robot(payload_image="Reg/Bad Image:1"),
            "robots.yaml: robot3.payload_image: 'Reg/Bad Image:1' is not a valid image reference",
        ),
        (robot(docker_users=["Alice"]), "robots.yaml: robot3.docker_users[0]: expected a user name, got 'Alice'"),
        (robot(docker_users="alice"), "robots.yaml: robot3.docker_users: expected a list, got 'alice'"),
        (
            robot(docker_usres=["alice"]),
            "robots.yaml: robot3.docker_usres: unknown setting (did you mean 'docker_users'?)",
        ),
        (robot(ssh_port=70000), "robots.yaml: robot3.ssh_port: expected at most 65535, got 70000"),
        (robot(ssh_port="22"), "robots.yaml: robot3.ssh_port: expected a whole number, got '22'"),
        (robot(x11_enabled="yes"), "robots.yaml: robot3.x11_enabled: expected true or false, got 'yes'"),
        (robot(x11_enabled=True), "robots.yaml: robot3.x11_user: required when x11_enabled is true: the desktop user"),
        (
            robot(payload_volumes=["maps:/maps"]),
            "robots.yaml: robot3.payload_volumes[0]: expected 'host_path:container_path[:ro]' with absolute paths, "
            "got 'maps:/maps'",
        ),
        (
            robot(payload_dir="/var/lib/../etc"),
            "robots.yaml: robot3.payload_dir: paths must not contain '..', got '/var/lib/../etc'",
        ),
        (
            robot(udev_rules_file="/etc/udev/robot.rules"),
            "robots.yaml: robot3.udev_rules_file: expected a file in /etc/udev/rules.d/ ending in .rules, "
            "got '/etc/udev/robot.rules'",
        ),
        (robot(docker_source="snap"), "robots.yaml: robot3.docker_source: expected one of docker, distro, got 'snap'"),
        (
            robot(payload_environment={"ROS DISTRO": "jazzy"}),
            "robots.yaml: robot3.payload_environment.'ROS DISTRO': expected an environment variable name, "
            "got 'ROS DISTRO'",
        ),
        (
            robot(ros_master_uri="http://master:11311", ros_domain_id=3),
            "robots.yaml: robot3.ros_master_uri: set either ros_master_uri (ROS 1) or ros_domain_id (ROS 2), not both",
        ),
        (
            {"robots": {"hosts": {"robot3": {"address": "10.0.0.1"}}}},
            "robots.yaml: robot3.payload_image: required: the payload image, pinned by tag or digest",
        ),
        (
            {"robots": {"vars": {"payload_imag": "x:1"}, "hosts": {}}},
            "robots.yaml: robots.vars.payload_imag: unknown setting (did you mean 'payload_image'?)",
        ),
        # Top-level keys are groups, as in Ansible: a misspelt robots holds hosts of no kind.
        (
            {"robot": {"hosts": {"robot3": GOOD_HOST}}},
            "robots.yaml: robot3: in neither a robots nor a laptops group (groups: robot) (did you mean 'robots'?)",
        ),
        ({"robots": {"hosts": {"a b": GOOD_HOST}}}, "robots.yaml: 'a b': invalid host name (letters, digits, . _ -)"),
        (
            {"robots": {"hosts": {"r1": GOOD_HOST}}, "laptops": {"hosts": {"r1": {**GOOD_HOST, "x11_user": "a"}}}},
            "robots.yaml: r1: declared in both robots and laptops",
        ),
        (
            {"robots": {"hosts": {"r1": ["not", "a", "mapping"]}}},
            "robots.yaml: r1: expected a mapping of settings, got a list",
        ),
    ],
)
def test_bad_data_gets_one_clear_line(doc, expected):
    assert expected in fleet_problems(doc)


def test_every_problem_is_reported_at_once():
    doc = robot(ssh_port="22", docker_users=["Alice"], udev_sensors=[{"name": "x", "subsystem": "tty", "serial": 1}])
    assert len(fleet_problems(doc)) == 3


def test_a_bad_value_in_all_vars_hides_none_of_the_hosts_own():
    """Issue 54, item 6: a refused all.vars value (an allowing flag that is not
    a boolean, a list that is not one) left the rules that read it unchecked on
    every host, whose own problems showed only once it was fixed."""
    latest = "reg.example.com/ros/payload:latest"
    sensors = [{"name": "a", "subsystem": "tty", "serial": "1"}, {"name": "a", "subsystem": "tty", "serial": "2"}]
    hosts = {
        "robot1": {"address": "10.0.0.1", "payload_image": latest, "udev_sensors": sensors},
        "robot2": {
            "address": "10.0.0.2",
            "payload_image": latest,
            "payload_allow_latest": False,  # its own value replaces the refused one
            "udev_allow_world_writable": False,
            "udev_sensors": [{"name": "b", "subsystem": "tty", "serial": "1", "mode": "0666"}],
        },
    }
    doc = {
        "all": {"vars": {"ssh_user": "ops", "payload_allow_latest": "yes", "udev_allow_world_writable": "no"}},
        "robots": {"hosts": hosts},
    }
    pinned = "pin a version or digest (or set payload_allow_latest: true)"
    assert fleet_problems(doc) == [
        "robots.yaml: all.vars.payload_allow_latest: expected true or false, got 'yes'",
        "robots.yaml: all.vars.udev_allow_world_writable: expected true or false, got 'no'",
        "robots.yaml: robot1.udev_sensors[1].name: duplicate sensor name 'a' (also udev_sensors[0])",
        "robots.yaml: robot1.udev_sensors[1].symlink: /dev/robot/a is already used by udev_sensors[0]",
        f"robots.yaml: robot1.payload_image: {latest!r} uses the moving tag 'latest'; {pinned}",
        "robots.yaml: robot2.udev_sensors[0].mode: 0666 is world-writable; use a group "
        "(or set udev_allow_world_writable)",
        f"robots.yaml: robot2.payload_image: {latest!r} uses the moving tag 'latest'; {pinned}",
    ]


def test_a_refused_value_a_host_replaces_keeps_no_rule_off_the_hosts_own():
    latest = "reg.example.com/ros/payload:latest"
    doc = {
        "all": {"vars": {"ssh_user": "ops", "payload_image": 42}},
        "robots": {"hosts": {"r1": {"payload_image": latest}}},
    }
    assert fleet_problems(doc) == [
        "robots.yaml: all.vars.payload_image: expected a string, got 42; quote it",
        f"robots.yaml: r1.payload_image: {latest!r} uses the moving tag 'latest'; pin a version or digest "
        "(or set payload_allow_latest: true)",
    ]


def test_a_refused_sensor_hides_nothing_of_the_others():
    """A sensor refused on its own leaves the others' passthrough checked."""
    services = {"driver": {"image": "reg.example.com/ros/driver:1.0"}, "ui": {"image": "reg.example.com/ros/ui:1.0"}}
    sensors = [{"name": "a", "subsystem": "camera", "serial": "1"}, {"name": "b", "subsystem": "tty", "serial": "2"}]
    problems = fleet_problems(robot(payload_image=None, payload_services=services, udev_sensors=sensors))
    assert (
        "robots.yaml: robot3.udev_sensors[1]: name the service(s) that use it (services: [...]); no service asks "
        "for devices" in problems
    ), problems


def test_a_refused_flag_allows_nothing_of_docker():
    options = {"hosts": ["tcp://0.0.0.0:2375"]}
    problems = fleet_problems(robot(docker_daemon_options=options, docker_allow_unauthenticated_tcp="yes"))
    assert len(problems) == 2 and "opens the Docker API on TCP without TLS client verification" in problems[1]


def test_yaml_syntax_error_names_the_line(tmp_path):
    path = tmp_path / "robots.yaml"
    path.write_text("robots:\n  hosts:\n    r1: {address: 10.0.0.1\n    r2: {}\n")
    with pytest.raises(fleet.FleetError) as error:
        fleet.load(path)
    (line,) = error.value.lines
    assert line.startswith(
        fleet.display_path(path) + ": line 3: YAML error: a flow mapping opened here (column 9) is not closed: "
    )


def test_duplicate_hosts_in_yaml_are_refused(tmp_path):
    path = tmp_path / "robots.yaml"
    path.write_text("robots:\n  hosts:\n    r1: {}\n    r1: {}\n")
    with pytest.raises(fleet.FleetError) as error:
        fleet.load(path)
    assert "duplicate key 'r1'" in error.value.lines[0]


@pytest.mark.parametrize(
    "path",
    [
        "/var/run/lock/robot.lock",
        "/var/lock/x",
        "/run/shm/x",
        "/var/run/shm/x",
        "/run/user/1000/payload",
        "/var/run/user/1000/x",
    ],
)
def test_world_writable_directories_are_refused_under_their_other_names(path):
    """/var/run is /run on Debian and Ubuntu: /var/run/lock is the 1777 /run/lock."""
    lines = fleet_problems(robot(payload_update_lock_path=path))
    assert len(lines) == 1 and "is in the world-writable" in lines[0], lines
    assert fleet_problems(robot(payload_update_lock_path="/var/run/robot-payload/update.lock")) == []


def test_an_ipv6_scope_is_a_name_not_anything_after_the_percent_sign():
    """Python's ipaddress takes anything after % as the scope, a newline too:
    an address that carries a second line into a config file is refused."""
    lines = fleet_problems(robot(address="fe80::1%a\nallow all"))
    assert len(lines) == 1
    assert "robot3.address: expected a host name or an IP address, got 'fe80::1%a\\nallow all'" in lines[0]
    assert "\n" not in lines[0]
    assert fleet_problems(robot(address="fe80::1%eth0")) == []
