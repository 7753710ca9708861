"""payload_image_pins: a pull release's digests (ref -> sha256:...) given to
the deploy by the robot's agent.  Each pinned image runs as
repository:tag@digest; pins that leave an image of the project out, bad
digests and references, and pins with push delivery are refused with one
line before anything changes; a converged host with the same pins plans
nothing (one SSH command: the snapshot)."""

import json

import pytest
import yaml
from pyinfra_cli.util import parse_cli_arg

from robotfleet import deploy_roles
from robotfleet.commands import rollout_judge
from roles.payload import compose, digests, report
from roles.payload import pins as publish_pins
from tests.fixtures import robot_fleet
from tests.unit.harness import ROBOT, converged, desired_compose, find, fleet_problems, merged, plan

REG = "reg.example.com"
A, B, C = ("sha256:" + x * 64 for x in "abc")
PAYLOAD = f"{REG}/ros/payload:1.1"
TWO = {"driver": {"image": f"{REG}/ros/driver:2.0"}, "slam": {"image": f"{REG}/ros/slam@{C}"}}
ROSCORE = f"{REG}/ros:noetic-ros-core"


def rendered(data: dict) -> dict:
    """The compose document as written to the robot (dumped and read back)."""
    return yaml.safe_load(compose.dump(desired_compose(merged("robots", data), "10.0.0.9")))


def images_of(doc: dict) -> dict:
    return {name: service["image"] for name, service in doc["services"].items()}


# --- the rendered compose document ---------------------------------------------------


def test_a_pinned_image_runs_by_its_digest_and_keeps_its_tag():
    doc = rendered({**ROBOT, "payload_image": PAYLOAD, "payload_image_pins": {PAYLOAD: A}})
    assert images_of(doc) == {"payload": f"{PAYLOAD}@{A}"}
    without = rendered({**ROBOT, "payload_image": PAYLOAD})
    assert {**doc, "services": {}} == {**without, "services": {}}  # nothing but the image changes
    assert {k: v for k, v in doc["services"]["payload"].items() if k != "image"} == {
        k: v for k, v in without["services"]["payload"].items() if k != "image"
    }


def test_every_service_and_the_roscore_of_the_preset_run_by_their_pins():
    data = {
        **ROBOT,
        "payload_image": None,
        "payload_services": TWO,
        "ros_preset": "ros1",
        "ros_roscore": True,
        "ros_roscore_image": ROSCORE,
        "payload_image_pins": {f"{REG}/ros/driver:2.0": A, f"{REG}/ros/slam@{C}": C, ROSCORE: B},
    }
    assert images_of(rendered(data)) == {
        "roscore": f"{ROSCORE}@{B}",
        "driver": f"{REG}/ros/driver:2.0@{A}",
        "slam": f"{REG}/ros/slam@{C}",
    }
    assert fleet_problems(robot_fleet(**{k: v for k, v in data.items() if k != "udev_sensors"})) == []


def test_pins_for_images_the_project_does_not_use_are_ignored():
    data = {
        **ROBOT,
        "payload_image": PAYLOAD,
        "payload_image_pins": {PAYLOAD: A, f"{REG}/ros/other:9": B, f"{REG}/ros/payload:1.0": C},
    }
    assert images_of(rendered(data)) == {"payload": f"{PAYLOAD}@{A}"}
    assert fleet_problems(robot_fleet(payload_image=PAYLOAD, payload_image_pins=data["payload_image_pins"])) == []


def test_no_pins_leave_the_document_as_it_was():
    assert rendered({**ROBOT, "payload_image": PAYLOAD, "payload_image_pins": {}}) == rendered(
        {**ROBOT, "payload_image": PAYLOAD}
    )


def test_what_publish_pins_is_what_the_deploy_looks_up():
    """The release record's keys are the pins part's refs (robotfleet
    publish); given back as the setting, they cover the project whole."""
    data = merged(
        "robots",
        {
            **ROBOT,
            "payload_image": None,
            "payload_services": TWO,
            "ros_preset": "ros1",
            "ros_roscore": True,
            "ros_roscore_image": ROSCORE,
        },
    )
    given = {ref: B for ref in publish_pins.PINS.refs(data)}
    assert publish_pins.PINS.setting == digests.SETTING
    assert digests.problems({**data, digests.SETTING: {**given, f"{REG}/ros/slam@{C}": C}}) == []
    assert all("@sha256:" in image for image in images_of(rendered({**data, digests.SETTING: given})).values())


# --- refusals: one line each, naming host and field -------------------------------------


@pytest.mark.parametrize(
    "settings, line",
    [
        (
            {"payload_image_pins": {f"{REG}/ros/other:1": A}},
            f"robot3.payload_image_pins: no digest for {PAYLOAD}: the pins must cover every image of the project "
            "(1 here), or that image would run whatever its tag names now",
        ),
        (
            {"payload_image_pins": {PAYLOAD: "sha256:abc"}},
            f"robot3.payload_image_pins.{PAYLOAD}: expected a digest: sha256: and 64 lowercase hex digits, got "
            "'sha256:abc'",
        ),
        (
            {"payload_image_pins": {PAYLOAD: A.upper()}},
            f"robot3.payload_image_pins.{PAYLOAD}: expected a digest: sha256: and 64 lowercase hex digits, got "
            f"'{A.upper()}'",
        ),
        (
            {"payload_image_pins": {"Reg/Bad Ref": A}},
            "robot3.payload_image_pins.'Reg/Bad Ref': 'Reg/Bad Ref' is not a valid image reference",
        ),
        (
            {"payload_image_pins": '{"broken": '},
            "robot3.payload_image_pins: expected a mapping image -> digest, got '{\"broken\": '; on --data give JSON "
            'text: payload_image_pins=\'{"reg/ros/payload:1.1": "sha256:..."}\'',
        ),
        (
            {"payload_image_pins": {PAYLOAD: A}, "payload_delivery": "push"},
            "robot3.payload_image_pins: pins need payload_delivery: pull: a pushed image arrives by docker load, which "
            "keeps its image id but not the registry digest a release pins, so the robot could not run it by that "
            "digest",
        ),
    ],
)
def test_a_bad_pin_is_one_line_naming_host_and_field(settings, line):
    assert fleet_problems(robot_fleet(payload_image=PAYLOAD, **settings)) == [f"robots.yaml: {line}"]


def test_a_service_the_pins_leave_out_is_named_with_the_others_in_one_line():
    doc = robot_fleet(
        payload_services=TWO,
        ros_preset="ros1",
        ros_roscore=True,
        ros_roscore_image=ROSCORE,
        payload_image_pins={f"{REG}/ros/driver:2.0": A},
    )
    assert fleet_problems(doc) == [
        f"robots.yaml: robot3.payload_image_pins: no digest for {REG}/ros/slam@{C}, {ROSCORE}: the pins must "
        "cover every image of the project (3 here), or that image would run whatever its tag names now"
    ]


def test_a_pin_that_contradicts_the_image_s_own_digest_is_refused():
    ref = f"{REG}/ros/payload@{A}"
    assert fleet_problems(robot_fleet(payload_image=ref, payload_image_pins={ref: B})) == [
        f"robots.yaml: robot3.payload_image_pins.{ref}: {B} differs from the digest the image names itself ({A})"
    ]
    assert fleet_problems(robot_fleet(payload_image=ref, payload_image_pins={ref: A})) == []


# --- the deploy: --data, before any change, and converged ----------------------------------


def test_pins_given_on_the_command_line_are_refused_before_anything_changes():
    """--data never went through the fleet file: the run checks it first,
    fails that host with one line and sends it nothing else."""
    pinned = {**ROBOT, "payload_image": PAYLOAD}
    snap = converged("robots", pinned, "debian-13")
    result = plan(
        {
            "r1": ("robots", {**pinned, "payload_image_pins": {f"{REG}/ros/other:1": A}}, snap),
            "r2": ("robots", {**pinned, "payload_image_pins": {PAYLOAD: A}}, snap),
        }
    )
    assert result.failed == {"r1"} and len(result["r1"]) == 1
    assert f"settings: payload_image_pins: no digest for {PAYLOAD}" in result["r1"][0]
    assert "\n" not in result["r1"][0].split("echo ", 1)[1].rstrip("\n")
    assert find(result["r2"], "payloadctl apply")


def test_a_converged_host_with_the_same_pins_plans_nothing_and_a_new_digest_releases():
    data = {**ROBOT, "payload_image": PAYLOAD, "payload_image_pins": {PAYLOAD: A}}
    snap = converged("robots", data, "debian-13")
    assert plan({"r1": ("robots", data, snap)})["r1"] == []  # the snapshot only
    commands = plan({"r1": ("robots", {**data, "payload_image_pins": {PAYLOAD: B}}, snap)})["r1"]
    assert len(commands) == 1 and "payloadctl apply" in commands[0]
    spec = json.loads(commands[0].stdin)["spec"]
    assert spec["compose"]["services"]["payload"]["image"] == f"{PAYLOAD}@{B}" and spec["delivery"] == "pull"


def test_the_agent_s_json_text_reaches_the_setting_as_pyinfra_reads_it():
    """pyinfra's --data turns JSON text into a mapping (parse_cli_arg);
    the rollout command reads its --data the same way, so what a wave
    waits for is the image as it runs (payloadctl records it by that ref)."""
    text = json.dumps({PAYLOAD: A})
    data = merged("robots", {**ROBOT, "payload_image": PAYLOAD, "payload_image_pins": parse_cli_arg(text)})
    assert deploy_roles.registry().data_problems(data) == []
    assert images_of(rendered(data)) == {"payload": f"{PAYLOAD}@{A}"}
    overrides = rollout_judge.read_overrides([f"payload_image_pins={text}", "payload_force=true", "x"])
    assert overrides == {"payload_image_pins": {PAYLOAD: A}, "payload_force": True}
    target = rollout_judge.targets_of(
        deploy_roles.roles(), dict(merged("robots", {**ROBOT, "payload_image": PAYLOAD})), overrides
    )
    assert target["payload"] == [f"{PAYLOAD}@{A}"]
    row = {
        "reachable": True,
        "image_refs": [f"{PAYLOAD}@{A}"],
        "release_state": "active",
        "state": "running",
        "health": "healthy",
    }
    assert report.missing(row, target["payload"]) is None
    assert report.missing({**row, "image_refs": [PAYLOAD]}, target["payload"]).startswith(f"runs {PAYLOAD}, not ")


# --- what a robot runs, judged against what the release pinned ------------------------


def test_a_reference_runs_the_wanted_image_by_its_digest_or_else_its_tag():
    assert digests.runs(f"{PAYLOAD}@{A}", f"{PAYLOAD}@{A}")
    assert digests.runs(f"{PAYLOAD}@{A}", f"{REG}/ros/payload@{A}")  # the digest decides; the tag is for people
    assert not digests.runs(f"{PAYLOAD}@{A}", f"{PAYLOAD}@{B}")
    assert not digests.runs(PAYLOAD, f"{PAYLOAD}@{A}")  # a tag alone may name anything now
    assert digests.runs(f"{PAYLOAD}@{A}", PAYLOAD)  # the fleet file's tag, as a release resolved it
    assert not digests.runs(f"{REG}/ros/payload:1.0@{A}", PAYLOAD)
    assert not digests.runs(f"{REG}/ros/other:1.1@{A}", f"{REG}/ros/payload@{A}")
    assert digests.shown(f"{PAYLOAD}@{A}", f"{REG}/ros/payload@{A}") == f"{PAYLOAD}@{A}"
    assert digests.shown(PAYLOAD, f"{REG}/ros/payload@{B}") == f"{PAYLOAD}@{B}"
    assert (
        digests.shown("offline.invalid/ros/payload:1.1", "offline.invalid/ros/payload:1.1")
        == "offline.invalid/ros/payload:1.1"
    )  # pushed: no registry digest


def test_a_pull_robot_running_its_release_by_digest_is_not_reported_missing_its_tag():
    """The user's fleet: payload_image: reg:5000/team/payload:2 in all.vars,
    no health check.  The robot runs reg:5000/team/payload:2@sha256:...;
    neither the converge run (the release's pins) nor status (the fleet
    file's tag) may call that a miss; another digest is one."""
    from robotfleet.pull.operator.publishing import HostData
    from robotfleet.pull.robot import converge

    image = "reg:5000/team/payload:2"
    data = merged("robots", {**ROBOT, "payload_image": image})
    row = {
        "reachable": True,
        "image_refs": [f"{image}@{A}"],
        "release_state": "active",
        "state": "running",
        "health": report.NO_CHECK,
    }
    roles = deploy_roles.roles()
    assert converge.missing(roles, HostData(data), row) == []  # status's drift reads the fleet file like this
    assert converge.missing(roles, HostData({**data, digests.SETTING: {image: A}}), row) == []
    other = converge.missing(roles, HostData({**data, digests.SETTING: {image: B}}), row)
    assert other == [{"role": "payload", "why": f"runs {image}@{A}, not {image}@{B}"}]
