"""How the payload's containers stop (issue 29 item 5), in the rendered
compose document: the ROS presets' stop signal, the grace period and an
init process, each on every service unless the service sets its own."""

import pytest
import yaml

from roles.payload import compose, problems
from tests.unit.harness import ROBOT, converged, desired_compose, fleet_problems, merged, plan

REG = "reg.example.com"
TWO = {"driver": {"image": f"{REG}/ros/driver:2.0"}, "slam": {"image": f"{REG}/ros/slam:1.0"}}


def rendered(extra: dict) -> dict:
    data = merged("robots", {"payload_image": None, **extra})
    return yaml.safe_load(compose.dump(desired_compose(data, "10.0.0.9")))


def test_without_settings_docker_stops_as_it_always_did():
    service = rendered({"payload_image": f"{REG}/ros/payload:1.0"})["services"]["payload"]
    assert not {"stop_signal", "stop_grace_period", "init"} & set(service)


@pytest.mark.parametrize(
    "preset, extra",
    [
        ("ros1", {"ros_roscore": True, "ros_roscore_image": f"{REG}/ros:noetic-ros-core"}),
        ("ros2", {}),
    ],
)
def test_ros_presets_stop_every_service_with_sigint(preset, extra):
    doc = rendered({"payload_services": TWO, "ros_preset": preset, **extra})
    assert {name: s.get("stop_signal") for name, s in doc["services"].items()} == {
        name: "SIGINT" for name in doc["services"]
    }
    assert len(doc["services"]) == (3 if preset == "ros1" else 2)  # roscore too
    assert problems.schema_problems(doc) == []


def test_a_service_keeps_its_own_stop_signal_and_settings_reach_every_service():
    services = dict(TWO, slam={**TWO["slam"], "stop_signal": "SIGTERM", "init": False, "stop_grace_period": "1m"})
    doc = rendered(
        {"payload_services": services, "ros_preset": "ros2", "payload_stop_grace_period": 3, "payload_init": True}
    )
    driver, slam = doc["services"]["driver"], doc["services"]["slam"]
    assert (driver["stop_signal"], driver["stop_grace_period"], driver["init"]) == ("SIGINT", "3s", True)
    assert (slam["stop_signal"], slam["stop_grace_period"], slam["init"]) == ("SIGTERM", "1m", False)
    assert problems.schema_problems(doc) == []


def test_the_single_image_payload_gets_the_grace_period_and_init():
    service = rendered(
        {"payload_image": f"{REG}/ros/payload:1.0", "payload_stop_grace_period": 0, "payload_init": True}
    )["services"]["payload"]
    assert service["stop_grace_period"] == "0s" and service["init"] is True


@pytest.mark.parametrize(
    "settings, line",
    [
        (
            {"payload_stop_grace_period": -1},
            "robots.yaml: robot3.payload_stop_grace_period: expected at least 0, got -1",
        ),
        (
            {"payload_stop_grace_period": "10s"},
            "robots.yaml: robot3.payload_stop_grace_period: expected a whole number, got '10s'",
        ),
        ({"payload_init": "yes"}, "robots.yaml: robot3.payload_init: expected true or false, got 'yes'"),
    ],
)
def test_bad_stop_settings_are_one_line(settings, line):
    host = {"address": "10.0.0.3", "payload_image": f"{REG}/a:1", **settings}
    assert fleet_problems({"robots": {"hosts": {"robot3": host}}}) == [line]


def test_a_new_stop_setting_is_a_new_release():
    snap = converged("robots", ROBOT, "debian-13")
    assert plan({"r1": ("robots", ROBOT, snap)})["r1"] == []
    commands = plan({"r1": ("robots", {**ROBOT, "payload_init": True}, snap)})["r1"]
    assert len(commands) == 1 and "payloadctl apply" in commands[0]
