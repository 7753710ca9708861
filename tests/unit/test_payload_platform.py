"""A service's platform in the fleet file (Compose's ``platform`` key, or
``payload_platform`` for the single-image shorthand): checked like every
setting, merged per service like the rest of a group's services, and
refused on a robot of another architecture before anything of the payload
changes there."""

import json

from roles.payload import services
from tests.fixtures import robot_fleet as host_with
from tests.unit.harness import ROBOT, find, fleet_problems, fresh_host, plan

REG = "reg.example.com"


def test_the_shorthand_carries_its_platform_to_its_one_service():
    assert services.declared({"payload_image": f"{REG}/cam:2.0-arm64", "payload_platform": "linux/arm64"}) == {
        "payload": {"image": f"{REG}/cam:2.0-arm64", "platform": "linux/arm64"}
    }
    assert services.declared({"payload_image": f"{REG}/cam:2.0"}) == {"payload": {"image": f"{REG}/cam:2.0"}}
    assert services.platforms(
        {"payload_services": {"a": {"image": "x:1", "platform": "linux/arm64"}, "b": {"image": "y:1"}}}
    ) == {"a": "linux/arm64"}


def test_a_platform_is_checked_in_either_place():
    assert fleet_problems(host_with(payload_image=f"{REG}/a:1", payload_platform="arm64")) == [
        "robots.yaml: robot3.payload_platform: expected os/architecture[/variant] like linux/arm64, got 'arm64'"
    ]
    assert fleet_problems(host_with(payload_services={"cam": {"image": f"{REG}/a:1", "platform": "aarch64"}})) == [
        "robots.yaml: robot3.payload_services.cam.platform: expected os/architecture[/variant] like linux/arm64, "
        "got 'aarch64'"
    ]
    assert fleet_problems(host_with(payload_services={"cam": {"image": f"{REG}/a:1", "platform": 64}})) == [
        "robots.yaml: robot3.payload_services.cam.platform: expected os/architecture[/variant] like linux/arm64, got 64"
    ]
    assert fleet_problems(
        host_with(payload_services={"cam": {"image": f"{REG}/a:1"}}, payload_platform="linux/arm64")
    ) == [
        "robots.yaml: robot3.payload_platform: applies to the single-image payload; with payload_services "
        "give each service its own 'platform' key"
    ]
    assert (
        fleet_problems(host_with(payload_services={"cam": {"image": f"{REG}/a:1", "platform": "linux/arm/v7"}})) == []
    )


FLEET = f"""
x-arm64-robot: &arm64-robot
  payload_services:
    camera: {{image: "{REG}/vendor/cam:2.0-arm64", platform: linux/arm64}}
robots:
  vars:
    payload_services:
      camera: {{image: "{REG}/vendor/cam:2.0-amd64", platform: linux/amd64}}
      nav: {{image: "{REG}/ros/nav:1.0"}}
  hosts:
    nuc1: {{address: 10.0.0.1}}
    pi1:
      <<: *arm64-robot
      address: 10.0.0.2
"""


def test_robots_of_one_architecture_pin_a_vendors_per_architecture_tag_per_service():
    """A fleet file has the groups robots and laptops: robots of another
    architecture share their pins through an anchor, merged per service
    over the group's services like any host's payload_services."""
    from robotfleet import deploy_roles
    from robotfleet.fleet.validate import parse

    hosts = dict(parse(FLEET, "robots.yaml", deploy_roles.registry()).hosts("robots"))
    assert hosts["nuc1"]["payload_services"]["camera"]["platform"] == "linux/amd64"
    pi = hosts["pi1"]["payload_services"]
    assert pi["camera"] == {"image": f"{REG}/vendor/cam:2.0-arm64", "platform": "linux/arm64"}
    assert pi["nav"] == {"image": f"{REG}/ros/nav:1.0"}  # unpinned: Docker picks the robot's variant


def test_a_service_pinned_to_another_platform_fails_that_robot_before_the_payload_changes():
    arm64 = {
        **ROBOT,
        "payload_services": {"payload": {"image": f"{REG}/cam:2.0-amd64", "platform": "linux/amd64"}},
        "payload_image": None,
    }
    result = plan(
        {
            "pi1": ("robots", arm64, fresh_host("debian-13", "arm64")),
            "nuc1": ("robots", arm64, fresh_host("debian-13", "amd64")),
        }
    )
    assert result.failed == {"pi1"}
    refusal = [c for c in result["pi1"] if "refused" in c]
    assert (
        len(refusal) == 1
        and (
            "payload: @fake/pi1 is linux/arm64 but service payload pins platform "
            "linux/amd64: refused before anything switched"
        )
        in refusal[0]
    )
    assert not find(result["pi1"], "payloadctl") and not find(result["pi1"], "robot-payload.service")
    assert find(result["nuc1"], "payloadctl apply")


def test_the_pinned_platform_reaches_the_robot_in_the_release():
    data = {**ROBOT, "payload_platform": "linux/arm64"}
    result = plan({"pi1": ("robots", data, fresh_host("debian-13", "arm64"))})
    assert result.failed == set()
    apply = find(result["pi1"], "payloadctl apply")[0]
    request = json.loads(apply.stdin)
    assert request["spec"]["compose"]["services"]["payload"]["platform"] == "linux/arm64"
    assert request["run"]["host"] == "@fake/pi1"  # the robot's name in the fleet
