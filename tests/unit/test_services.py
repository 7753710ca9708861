"""The payload as a compose project: merging group/host service data, the
Compose Specification refusals (one line naming file, host, service, key),
sensors to services, and the rendered compose for the ROS presets."""

import json

import pytest
import yaml

from robotfleet import deploy_roles, status_parts
from robotfleet.commands import status
from roles.payload import compose, containers, presets, problems, services, takeover_plan
from tests.fixtures import robot_fleet as host_with
from tests.unit import harness as fleet
from tests.unit.harness import ROBOT, converged, desired_compose, fleet_problems, merged, plan

REG = "reg.example.com"
TWO = {
    "driver": {"image": f"{REG}/ros/driver:2.0", "devices": [], "environment": {"RATE": "10"}},
    "slam": {
        "image": f"{REG}/ros/slam:1.0",
        "ipc": "host",
        "cap_add": ["SYS_NICE"],
        "ulimits": {"rtprio": 99, "memlock": {"soft": -1, "hard": -1}},
        "shm_size": "1g",
        "tty": True,
        "stdin_open": True,
        "volumes": ["/etc/hosts:/etc/hosts:ro"],
    },
}


def fleet_of(group_vars: dict, hosts: dict) -> dict:
    return {"robots": {"vars": group_vars, "hosts": hosts}}


def test_host_changes_one_service_tag_and_keeps_the_rest_from_the_group():
    doc = fleet_of(
        {"payload_services": TWO},
        {
            "robot1": {"address": "10.0.0.1"},
            "robot2": {
                "address": "10.0.0.2",
                "payload_services": {
                    "driver": {"image": f"{REG}/ros/driver:2.1", "environment": {"DEBUG": "1"}},
                    "slam": None,
                    "bridge": {"image": f"{REG}/ros/bridge:0.3"},
                },
            },
        },
    )
    hosts = dict(fleet.check(doc, "robots.yaml").hosts("robots"))
    assert hosts["robot1"]["payload_services"] == TWO
    robot2 = hosts["robot2"]["payload_services"]
    assert robot2["driver"] == {
        "image": f"{REG}/ros/driver:2.1",
        "devices": [],
        "environment": {"RATE": "10", "DEBUG": "1"},
    }
    assert set(robot2) == {"driver", "bridge"}  # null removed slam
    assert TWO["driver"]["image"].endswith(":2.0")  # the group's data is not modified


def test_merge_replaces_lists_and_removes_keys_with_null():
    assert services.merge({"a": {"x": [1, 2], "y": 1}}, {"a": {"x": [3], "y": None}}) == {"a": {"x": [3]}}
    assert services.merge_layers([{"payload_services": {"a": {"image": "i:1"}}}, {}, None]) == {"a": {"image": "i:1"}}


def test_the_shorthand_document_is_unchanged_by_the_project_builder():
    data = merged(
        "robots",
        {
            "payload_image": f"{REG}/ros/payload:1.0",
            "payload_command": ["run"],
            "payload_volumes": ["/srv/maps:/maps:ro"],
            "payload_gpu": True,
            "udev_sensors": [{"name": "lidar", "subsystem": "tty", "serial": "A"}],
        },
    )
    # What the single-service builder made before there were several services.
    old = {
        "name": "robot-payload",
        "services": {
            "payload": {
                "image": f"{REG}/ros/payload:1.0",
                "restart": "unless-stopped",
                "network_mode": "host",
                "environment": {
                    "ROS_DOMAIN_ID": "0",
                    "NVIDIA_VISIBLE_DEVICES": "all",
                    "NVIDIA_DRIVER_CAPABILITIES": "compute,utility",
                },
                "labels": {"io.robot-fleet.payload": "robot-payload"},
                "command": ["run"],
                "volumes": ["/srv/maps:/maps:ro"],
                "devices": ["/dev/robot/lidar:/dev/robot/lidar"],
                "deploy": {
                    "resources": {
                        "reservations": {"devices": [{"driver": "nvidia", "count": "all", "capabilities": ["gpu"]}]}
                    }
                },
            }
        },
    }
    new = desired_compose(data, "10.0.0.1")
    assert new == old
    assert compose.dump(new) == compose.dump(old)  # same keys in the same order: no release on upgrade


def rendered(extra: dict, address="10.0.0.9", files_dir=None) -> dict:
    data = merged("robots", {"payload_image": None, **extra})
    return yaml.safe_load(compose.dump(desired_compose(data, address)))


def test_two_services_get_our_defaults_under_their_own_keys():
    doc = rendered(
        {
            "payload_services": TWO,
            "payload_environment": {"SITE": "lab"},
            "udev_sensors": [{"name": "lidar", "subsystem": "tty", "serial": "A"}],
        }
    )
    driver, slam = doc["services"]["driver"], doc["services"]["slam"]
    assert driver["image"] == f"{REG}/ros/driver:2.0"
    assert driver["restart"] == "unless-stopped" and driver["network_mode"] == "host"
    assert driver["environment"] == {"ROS_DOMAIN_ID": "0", "SITE": "lab", "RATE": "10"}
    assert driver["labels"] == {"io.robot-fleet.payload": "robot-payload"}
    assert driver["devices"] == ["/dev/robot/lidar:/dev/robot/lidar"]  # the service that asked for devices
    assert "devices" not in slam
    assert slam["ipc"] == "host" and slam["cap_add"] == ["SYS_NICE"] and slam["shm_size"] == "1g"
    assert slam["ulimits"] == {"rtprio": 99, "memlock": {"soft": -1, "hard": -1}}
    assert slam["volumes"] == ["/etc/hosts:/etc/hosts:ro"] and slam["tty"] is True
    assert problems.schema_problems(doc) == []


def test_a_sensor_goes_to_the_services_it_names():
    doc = rendered(
        {
            "payload_services": TWO,
            "udev_sensors": [
                {"name": "cam", "subsystem": "video4linux", "serial": "C", "services": ["slam"]},
                {"name": "imu", "subsystem": "tty", "serial": "I"},
                {"name": "dbg", "subsystem": "tty", "serial": "D", "passthrough": False},
            ],
        }
    )
    assert doc["services"]["slam"]["devices"] == ["/dev/robot/cam:/dev/robot/cam"]
    assert doc["services"]["driver"]["devices"] == ["/dev/robot/imu:/dev/robot/imu"]


def test_ros1_preset_with_roscore_service():
    doc = rendered(
        {
            "payload_services": TWO,
            "ros_preset": "ros1",
            "ros_roscore": True,
            "ros_roscore_image": f"{REG}/ros:noetic-ros-core",
        }
    )
    assert list(doc["services"]) == ["roscore", "driver", "slam"]
    roscore = doc["services"]["roscore"]
    assert roscore["image"] == f"{REG}/ros:noetic-ros-core" and roscore["command"] == ["roscore"]
    assert "depends_on" not in roscore
    for name in ("driver", "slam"):
        env = doc["services"][name]["environment"]
        assert env["ROS_MASTER_URI"] == "http://localhost:11311" and env["ROS_HOSTNAME"] == "10.0.0.9"
        assert "ROS_DOMAIN_ID" not in env
        assert doc["services"][name]["depends_on"] == {"roscore": {"condition": "service_healthy", "restart": True}}
    assert problems.schema_problems(doc) == []


def test_ros1_preset_with_an_external_master_and_one_service():
    doc = rendered(
        {
            "payload_image": f"{REG}/ros/payload:1.0",
            "ros_preset": "ros1",
            "ros_master_uri": "http://master:11311",
            "ros_hostname": "robot7",
        }
    )
    assert list(doc["services"]) == ["payload"]
    assert doc["services"]["payload"]["environment"] == {
        "ROS_MASTER_URI": "http://master:11311",
        "ROS_HOSTNAME": "robot7",
        "ROS_LOG_DIR": "/var/log/ros",
    }


@pytest.mark.parametrize(
    "profile, env",
    [
        (
            '<CycloneDDS xmlns="https://cdds.io/config"><Domain/></CycloneDDS>',
            {"CYCLONEDDS_URI": "file:///etc/ros/dds/p.xml", "RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp"},
        ),
        (
            '<?xml version="1.0"?><profiles xmlns="http://www.eprosima.com"/>',
            {
                "FASTRTPS_DEFAULT_PROFILES_FILE": "/etc/ros/dds/p.xml",
                "FASTDDS_DEFAULT_PROFILES_FILE": "/etc/ros/dds/p.xml",
                "RMW_IMPLEMENTATION": "rmw_fastrtps_cpp",
            },
        ),
    ],
)
def test_ros2_preset_with_a_dds_profile(tmp_path, monkeypatch, profile, env):
    (tmp_path / "dds").mkdir()
    (tmp_path / "dds" / "p.xml").write_text(profile)
    monkeypatch.setattr(presets, "FILES_DIR", tmp_path)
    monkeypatch.setattr(presets.dds_profile_text, "__defaults__", (tmp_path,))
    monkeypatch.setattr(presets.preset, "__defaults__", (tmp_path,))
    doc = rendered({"payload_services": TWO, "ros_preset": "ros2", "ros_domain_id": 42, "ros_dds_profile": "p.xml"})
    for service in doc["services"].values():
        assert service["ipc"] == "host"
        assert service["environment"]["ROS_DOMAIN_ID"] == "42"
        assert {k: service["environment"][k] for k in env} == env
        assert "/etc/robot-payload/p.xml:/etc/ros/dds/p.xml:ro" in service["volumes"]
        assert len(service["labels"][presets.PROFILE_LABEL]) == 16
    assert doc["services"]["driver"]["environment"]["RATE"] == "10"
    assert problems.schema_problems(doc) == []


def test_ros2_preset_keeps_a_service_s_own_ipc():
    doc = rendered({"payload_services": {"a": {"image": f"{REG}/a:1", "ipc": "shareable"}}, "ros_preset": "ros2"})
    assert doc["services"]["a"]["ipc"] == "shareable"


@pytest.mark.parametrize(
    "service, line",
    [
        (
            {"image": f"{REG}/a:1", "ipcc": "host"},
            "robots.yaml: robot3.payload_services.drv.ipcc: not a key of the Compose Specification (did you mean "
            "'ipc'?)",
        ),
        (
            {"image": f"{REG}/a:1", "restart": 5},
            "robots.yaml: robot3.payload_services.drv.restart: Compose Specification: 5 is not of type 'string'",
        ),
        (
            {"image": f"{REG}/a:1", "ulimits": {"rtprio": {"soft": "x"}}},
            "robots.yaml: robot3.payload_services.drv.ulimits.rtprio",
        ),
        (
            {"image": f"{REG}/a:1", "cap_add": "SYS_NICE"},
            "robots.yaml: robot3.payload_services.drv.cap_add: Compose Specification: 'SYS_NICE' is not of type "
            "'array'",
        ),
        (
            {"image": f"{REG}/a:1", "privileged": True},
            "robots.yaml: robot3.payload_services.drv.privileged: privileged containers are refused unless "
            "payload_allow_privileged is true (prefer devices / cap_add)",
        ),
        (
            {"image": f"{REG}/a:1", "volumes": ["/var/lib/robot-payload/current:/x"]},
            "robots.yaml: robot3.payload_services.drv.volumes[0]: /var/lib/robot-payload/current is inside "
            "/var/lib/robot-payload (the releases); mount a path outside it",
        ),
        (
            {"image": f"{REG}/a:1", "volumes": [{"type": "bind", "source": "./cfg", "target": "/cfg"}]},
            "robots.yaml: robot3.payload_services.drv.volumes[0]: relative path ./cfg would resolve inside the "
            "release directory; use an absolute host path",
        ),
        (
            {"image": f"{REG}/a:1", "env_file": ["/etc/robot.env", {"path": "cfg.env"}]},
            "robots.yaml: robot3.payload_services.drv.env_file[1]: cfg.env would be read from the release directory",
        ),
        (
            {"image": f"{REG}/a:1", "env_file": "cfg.env"},
            "robots.yaml: robot3.payload_services.drv.env_file: cfg.env would be read from the release directory",
        ),
        (
            {"image": f"{REG}/a:1", "build": "."},
            "robots.yaml: robot3.payload_services.drv.build: robots do not build images; push the image and set image",
        ),
        (
            {"image": f"{REG}/a:1", "environment": {"DEBUG": True}},
            "robots.yaml: robot3.payload_services.drv.environment.DEBUG: expected a string, got True (quote it",
        ),
        (
            {"image": f"{REG}/a:1", "profiles": ["debug"]},
            "robots.yaml: robot3.payload_services.drv.profiles: no profile is activated on the robot",
        ),
        (
            {"command": ["x"]},
            "robots.yaml: robot3.payload_services.drv.image: required: the service's image, pinned by tag or digest",
        ),
        ({"image": f"{REG}/a"}, f"robots.yaml: robot3.payload_services.drv.image: '{REG}/a' has no tag or digest"),
    ],
)
def test_a_bad_service_key_is_one_line_naming_file_host_service_and_key(service, line):
    lines = fleet_problems(host_with(payload_services={"drv": service}))
    assert len(lines) == 1, lines
    assert lines[0].startswith(line), lines


def test_schema_problems_in_a_group_name_each_host():
    lines = fleet_problems(
        fleet_of(
            {"payload_services": {"drv": {"image": f"{REG}/a:1", "shm_sise": "1g"}}},
            {"robot1": {"address": "a"}, "robot2": {"address": "b", "payload_services": {"drv": {"shm_sise": None}}}},
        )
    )
    assert lines == [
        "robots.yaml: robot1.payload_services.drv.shm_sise: not a key of the Compose "
        "Specification (did you mean 'shm_size'?)"
    ]


def test_refusals_that_need_the_whole_project():
    two_names = {
        "a": {"image": f"{REG}/a:1", "container_name": "ros"},
        "b": {"image": f"{REG}/b:1", "container_name": "ros"},
    }
    assert fleet_problems(host_with(payload_services=two_names)) == [
        "robots.yaml: robot3.payload_services.b.container_name: 'ros' is also the container_name of service a"
    ]
    assert fleet_problems(
        host_with(
            payload_services={"a": {"image": f"{REG}/a:1", "container_name": "old"}}, payload_replaces=["container:old"]
        )
    ) == [
        "robots.yaml: robot3.payload_services.a.container_name: 'old' is listed in payload_replaces: "
        "the takeover would stop this project's own container"
    ]
    assert fleet_problems(host_with(payload_image=f"{REG}/a:1", payload_services={"a": {"image": f"{REG}/a:1"}})) == [
        "robots.yaml: robot3.payload_services: set either payload_image (one service called payload) or "
        "payload_services, not both (set payload_image: null where payload_services is used)"
    ]
    assert fleet_problems(host_with(payload_services=TWO, payload_command=["x"])) == [
        "robots.yaml: robot3.payload_command: applies to the single-image payload; with payload_services "
        "give each service its own 'command' key"
    ]
    assert fleet_problems(
        host_with(
            payload_services=TWO, udev_sensors=[{"name": "cam", "subsystem": "tty", "serial": "C", "services": ["nav"]}]
        )
    ) == ["robots.yaml: robot3.udev_sensors[0].services: no service called 'nav' (services: driver, slam)"]
    no_devices = {"a": {"image": f"{REG}/a:1"}, "b": {"image": f"{REG}/b:1"}}
    assert fleet_problems(
        host_with(payload_services=no_devices, udev_sensors=[{"name": "cam", "subsystem": "tty", "serial": "C"}])
    ) == [
        "robots.yaml: robot3.udev_sensors[0]: name the service(s) that use it (services: [...]); "
        "no service asks for devices"
    ]
    assert fleet_problems(host_with(payload_services=TWO, payload_allow_privileged=True)) == []
    assert (
        fleet_problems(
            host_with(
                payload_services={"a": {"image": f"{REG}/a:1", "privileged": True}}, payload_allow_privileged=True
            )
        )
        == []
    )


def test_preset_refusals():
    image = {"payload_image": f"{REG}/a:1"}
    assert fleet_problems(host_with(**image, ros_preset="ros1")) == [
        "robots.yaml: robot3.ros_master_uri: required with ros_preset: ros1 unless ros_roscore is true"
    ]
    assert fleet_problems(host_with(**image, ros_preset="ros1", ros_roscore=True)) == [
        "robots.yaml: robot3.ros_roscore_image: required with ros_roscore: an image with roscore, pinned"
    ]
    assert fleet_problems(host_with(**image, ros_preset="ros2", ros_dds_profile="nope.xml")) == [
        "robots.yaml: robot3.ros_dds_profile: no file files/dds/nope.xml"
    ]
    assert fleet_problems(host_with(**image, ros_preset="ros3")) == [
        "robots.yaml: robot3.ros_preset: expected one of ros1, ros2, got 'ros3'"
    ]


def test_layer_shape_is_checked_where_it_was_written():
    assert fleet_problems(fleet_of({"payload_services": {"a b": {}}}, {"robot1": {"address": "a"}}))[0] == (
        "robots.yaml: robots.vars.payload_services.'a b': service names are letters, digits, . _ - "
        "(starting with a letter or digit)"
    )
    assert fleet_problems(host_with(payload_services=["a"]))[0] == (
        "robots.yaml: robot3.payload_services: expected a mapping of service name -> compose service"
    )


def test_the_schema_is_the_maintained_package_s_copy_with_its_licence():
    """roles/payload/vendor/ is check-jsonschema's copy (the release the test extra pins), so every
    operator's Python checks against the same schema; refreshing it: roles/payload/README.md."""
    from importlib import resources

    vendor = resources.files("check_jsonschema.builtin_schemas.vendor")
    assert problems.COMPOSE_SCHEMA.read_bytes() == (vendor / "compose-spec.json").read_bytes()
    licence = (vendor / "licenses" / "LICENSE.compose-spec").read_bytes()
    assert (problems.COMPOSE_SCHEMA.parent / "LICENSE.compose-spec").read_bytes() == licence
    assert "compose" in json.dumps(problems.compose_schema()["$id"]).lower()
    assert b"Apache License" in licence
    assert {"ipc", "cap_add", "ulimits", "shm_size", "tty", "stdin_open"} <= set(problems.service_keys())


# --- the deploy's side: what it reads and what it sends -------------------------


def probe_line(cid, name, image, project_label, running, policy):
    return json.dumps("\t".join([cid, name, image, project_label, running, policy]))


FOREIGN = "\n".join(
    [
        probe_line(
            "a" * 64,
            "/robot-payload-payload-1",
            f"{REG}/ros/payload@sha256:" + "1" * 64,
            "robot-payload",
            "true",
            "unless-stopped",
        ),
        probe_line("b" * 64, "/ros_payload", f"{REG}/ros/payload:1.0", "%!s(<nil>)", "true", "always"),
        probe_line("c" * 64, "/old_bridge", f"{REG}/other/bridge:1", "rosapp", "false", "always"),
        probe_line("d" * 64, "/unrelated", f"{REG}/other/db:1", "%!s(<nil>)", "true", "always"),
        probe_line("e" * 64, "/dead", f"{REG}/ros/payload:0.9", "%!s(<nil>)", "false", "no"),
    ]
)


def test_foreign_containers_are_found_by_repository_name_or_project():
    takeover = {"primary": f"{REG}/ros/payload", "container": [], "project": ["rosapp"]}
    found = takeover_plan.foreign(FOREIGN, "robot-payload", takeover)
    assert [(c["name"], c["restart"], c["running"], c["project"]) for c in found] == [
        ("ros_payload", "always", True, None),
        ("old_bridge", "always", False, "rosapp"),
    ]
    assert takeover_plan.takeover_line(found) == (
        "payload: taking over what runs the payload another way (stopped, restart policy no): "
        f"ros_payload ({REG}/ros/payload:1.0, running, restart always: it runs the payload's image); "
        f"old_bridge (compose project rosapp, {REG}/other/bridge:1, stopped, restart always: "
        "payload_replaces names its compose project)"
    )


def test_another_projects_container_of_a_common_image_is_left_alone():
    """A service of ours using a common image (a broker) must not stop the
    broker of another compose project on the robot (issue 17, item 3)."""
    broker = f"{REG}/lib/mosquitto:2"
    probe = "\n".join(
        [
            probe_line("f" * 64, "/homeauto-broker-1", broker, "homeauto", "true", "always"),
            probe_line("a" * 64, "/ros_payload", f"{REG}/ros/payload:1.0", "%!s(<nil>)", "true", "always"),
        ]
    )
    data = merged(
        "robots",
        {
            "payload_image": None,
            "payload_services": {"payload": {"image": f"{REG}/ros/payload:1.1"}, "broker": {"image": broker}},
        },
    )
    found = takeover_plan.foreign(probe, "robot-payload", takeover_plan.takeover_of(data))
    assert [c["name"] for c in found] == ["ros_payload"]
    named = merged("robots", {**data, "payload_replaces": ["container:homeauto-broker-1"]})
    assert [c["name"] for c in takeover_plan.foreign(probe, "robot-payload", takeover_plan.takeover_of(named))] == [
        "homeauto-broker-1",
        "ros_payload",
    ]


@pytest.mark.parametrize(
    "entry, line",
    [
        (
            "old",
            "robots.yaml: robot3.payload_replaces[0]: 'old' could be a container or a compose project: "
            "write container:old or project:old",
        ),
        (
            "image:old",
            "robots.yaml: robot3.payload_replaces[0]: expected container:NAME or project:NAME, got 'image:old'",
        ),
    ],
)
def test_payload_replaces_tells_containers_from_compose_projects(entry, line):
    assert fleet_problems(host_with(payload_image=f"{REG}/a:1", payload_replaces=[entry])) == [line]


def test_a_converged_robot_with_a_foreign_payload_container_releases_and_says_so(caplog):
    snap = converged("robots", ROBOT, "debian-13")
    assert plan({"r1": ("robots", ROBOT, snap)})["r1"] == []
    snap.probes[containers.PROBE] += "".join(f"f\t{line}\n" for line in FOREIGN.splitlines())
    commands = plan({"r1": ("robots", ROBOT, snap)})["r1"]
    assert len(commands) == 1 and "payloadctl apply" in commands[0] and "--restart" in commands[0]
    assert "[@fake/r1] payload: taking over what runs the payload another way" in caplog.text


def test_a_converged_two_service_robot_plans_nothing_and_a_new_tag_only_releases():
    data = {**ROBOT, "payload_image": None, "payload_services": TWO}
    snap = converged("robots", data, "debian-13")
    assert plan({"r1": ("robots", data, snap)})["r1"] == []
    newer = {**data, "payload_services": services.merge(TWO, {"slam": {"image": f"{REG}/ros/slam:1.1"}})}
    commands = plan({"r1": ("robots", newer, snap)})["r1"]
    assert len(commands) == 1 and "payloadctl apply" in commands[0] and "--restart" not in commands[0]


def test_the_documented_example_project_is_valid_and_uses_the_shipped_profile():
    from tests.fixtures import ROOT

    readme = (ROOT / "roles" / "payload" / "README.md").read_text()
    section = readme.split("## The payload as a compose project", 1)[1]
    example = yaml.safe_load(section.split("```yaml\n", 1)[1].split("```", 1)[0])
    example["robots"]["hosts"]["robot2"]["address"] = "10.0.0.2"
    hosts = dict(fleet.check(example, "README.md").hosts("robots"))
    robot2 = hosts["robot2"]["payload_services"]
    assert robot2["slam"]["image"].endswith(":1.5.0-rc1") and robot2["slam"]["shm_size"] == "1g"
    assert presets.dds_vendor((presets.FILES_DIR / "dds" / "cyclonedds-localhost.xml").read_text()) == "cyclonedds"


def test_status_shows_each_service_image_with_its_tag_state_and_health():
    """Each service's image as the release names it (its tag) with the
    digest it runs by; a container without a health check says so."""
    digest, payload = "reg/ros/driver@sha256:" + "d" * 64, "reg/ros/payload@sha256:" + "e" * 64
    report = {
        "current": {
            "id": "r2",
            "images": {
                "reg/ros/driver:2.0": {"pinned": digest},
                "reg/ros/payload:1.0@sha256:" + "e" * 64: {"pinned": payload},
            },
        },
        "containers": [],
        "services": {
            "payload": {"image": payload, "state": "running", "health": "healthy"},
            "driver": {"image": digest, "state": "restarting", "health": None},
        },
    }
    roles = deploy_roles.roles()
    row = status_parts.row("robot1", roles, {"payload": json.dumps(report)})
    assert row["state"] == "driver:restarting, payload:running"
    assert row["health"] == "driver:no check, payload:healthy"
    line = status.table([row], status_parts.columns(roles)).splitlines()[1]
    assert f"driver=reg/ros/driver:2.0@sha256:{'d' * 12}, payload=reg/ros/payload:1.0@sha256:{'e' * 12}" in line


def test_a_service_s_values_reach_the_container_verbatim():
    doc = rendered(
        {
            "payload_services": {
                "a": {"image": f"{REG}/a:1", "command": ["sh", "-c", "echo $HOME"], "environment": {"PS1": "$ "}}
            },
            "payload_environment": {"X": "a$b"},
        }
    )
    service = doc["services"]["a"]
    assert service["command"] == ["sh", "-c", "echo $$HOME"]
    assert service["environment"]["PS1"] == "$$ " and service["environment"]["X"] == "a$$b"


@pytest.mark.parametrize(
    "service, field, what",
    [
        ({"cap_add": ["SYS_NICE", "ALL"]}, "cap_add[1]", "cap_add ALL"),
        ({"cap_add": ["sys_admin"]}, "cap_add[0]", "cap_add sys_admin"),
        ({"pid": "host"}, "pid", "pid: host"),
        ({"userns_mode": "host"}, "userns_mode", "userns_mode: host"),
        ({"security_opt": ["seccomp=unconfined"]}, "security_opt[0]", "security_opt seccomp=unconfined"),
        ({"volumes": ["/var/run/docker.sock:/var/run/docker.sock"]}, "volumes[0]", "mounting /var/run/docker.sock"),
        (
            {"volumes": [{"type": "bind", "source": "/run/docker.sock", "target": "/d.sock"}]},
            "volumes[0]",
            "mounting /run/docker.sock",
        ),
        ({"volumes": ["/:/host:ro"]}, "volumes[0]", "mounting /"),
    ],
)
def test_keys_that_hand_a_container_the_robot_are_refused_like_privileged(service, field, what):
    """The gate is a guard against mistakes, not a boundary (the fleet file is
    trusted): the same opt-in as privileged (issue 17, item 11)."""
    lines = fleet_problems(host_with(payload_services={"drv": {"image": f"{REG}/a:1", **service}}))
    assert lines == [
        f"robots.yaml: robot3.payload_services.drv.{field}: {what} gives the container root on the "
        "robot: refused unless payload_allow_privileged is true"
    ]
    assert (
        fleet_problems(
            host_with(payload_services={"drv": {"image": f"{REG}/a:1", **service}}, payload_allow_privileged=True)
        )
        == []
    )


def test_the_single_image_payload_cannot_mount_the_docker_socket_either():
    lines = fleet_problems(host_with(payload_image=f"{REG}/a:1", payload_volumes=["/var/run/docker.sock:/d.sock"]))
    assert lines == [
        "robots.yaml: robot3.payload_volumes[0]: mounting /var/run/docker.sock gives the container root "
        "on the robot: refused unless payload_allow_privileged is true"
    ]
    assert (
        fleet_problems(
            host_with(
                payload_services={
                    "drv": {"image": f"{REG}/a:1", "cap_add": ["SYS_NICE"], "volumes": ["/var/lib/maps:/maps"]}
                }
            )
        )
        == []
    )


def test_another_compose_project_running_the_payload_image_is_left_alone():
    """The deploy says the same as payloadctl does (issue 27, item 2): a
    container of the primary image in another compose project (homeauto) is
    not taken over; in no project, or in the project the robot's current
    release recorded, it is."""
    probe = "\n".join(
        [
            probe_line("f" * 64, "/homeauto-bridge-1", f"{REG}/ros/payload:1.0", "homeauto", "true", "always"),
            probe_line("a" * 64, "/ros_payload", f"{REG}/ros/payload:1.0", "%!s(<nil>)", "true", "always"),
            probe_line("b" * 64, "/ros-old-payload-1", f"{REG}/ros/payload:0.9", "ros-old", "true", "always"),
        ]
    )
    takeover = {"primary": f"{REG}/ros/payload", "container": [], "project": []}
    assert [c["name"] for c in takeover_plan.foreign(probe, "robot-payload", takeover)] == ["ros_payload"]
    recorded = takeover_plan.takeover_rule.recorded_projects(
        {"project": "ros-old", "taken_over": [{"project": "rosapp"}]}, "robot-payload"
    )
    assert recorded == ["ros-old", "rosapp"]
    found = takeover_plan.foreign(probe, "robot-payload", takeover, recorded)
    assert [(c["name"], c["why"]) for c in found] == [
        ("ros_payload", "it runs the payload's image"),
        (
            "ros-old-payload-1",
            "it runs the payload's image in compose project ros-old, which this robot's payload used before",
        ),
    ]
    named = takeover_plan.foreign(probe, "robot-payload", {**takeover, "project": ["homeauto"]})
    assert [c["name"] for c in named] == ["homeauto-bridge-1", "ros_payload"]
