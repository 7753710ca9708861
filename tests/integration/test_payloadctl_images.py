"""payloadctl's images (tests/integration/payloadrobot.py): the robot's
platform checked before anything switches, images present by digest not
pulled again, images a release on media left."""


def test_an_image_for_another_platform_is_refused_before_anything_switches(robot):
    robot.architecture("arm64")
    robot.image("reg/ros/payload:1.1", platform="linux/amd64")
    result = robot.apply("reg/ros/payload:1.1")
    assert result.returncode == 1
    line = [found for found in result.stderr.splitlines() if "refused" in found]
    assert line == [
        "payload: pi1 is linux/arm64 but image reg/ros/payload:1.1 is linux/amd64 only: "
        "refused before anything switched"
    ]
    assert robot.pointers() == ("r1", None) and robot.releases.all() == ["r1"]  # no release was even written
    assert not any(entry.startswith("docker compose") for entry in robot.state()["log"])


def test_the_robots_own_platform_is_kept_with_the_release(robot):
    robot.architecture("arm64")
    robot.image("reg/ros/payload:1.1", platform="linux/arm64")
    result = robot.apply("reg/ros/payload:1.1")
    assert result.returncode == 0, result.stderr
    current, _ = robot.pointers()
    assert robot.releases.record(current)["images"]["reg/ros/payload:1.1"]["platform"] == "linux/arm64"
    assert "docker pull -q reg/ros/payload:1.1" in robot.state()["log"]  # Docker picks the variant


def test_an_image_present_by_the_digest_it_names_is_not_pulled_again(robot):
    """A pull robot's prefetch (robotfleet/pull/robot/prefetch.py) pulled it
    before the window: the apply switches, the registry unreachable then."""
    pinned = "reg/ros/payload:1.1@sha256:" + "c" * 64
    for ref in (pinned, "reg/ros/payload@sha256:" + "c" * 64):  # as the release names it, as compose runs it
        robot.image(ref, pull="fail")
    robot.image("reg/ros/payload:1.2", pull="fail")
    result = robot.apply(pinned)
    assert result.returncode == 0, result.stderr
    assert not [entry for entry in robot.state()["log"] if entry.startswith("docker pull")]
    robot.apply("reg/ros/payload:1.2", run_id="run-2", pull_timeout=3)  # a tag may name another image now: asked for
    assert "docker pull -q reg/ros/payload:1.2" in robot.state()["log"]


def test_a_service_that_pins_its_platform_is_pulled_for_that_platform(robot):
    robot.architecture("arm64")
    robot.image("reg/ros/camera:2.0-arm64", platform="linux/arm64")
    compose = {
        "name": "robot-payload",
        "services": {"payload": {"image": "reg/ros/camera:2.0-arm64", "platform": "linux/arm64"}},
    }
    result = robot.apply("reg/ros/camera:2.0-arm64", compose=compose)
    assert result.returncode == 0, result.stderr
    assert "docker pull -q --platform linux/arm64 reg/ros/camera:2.0-arm64" in robot.state()["log"]


def test_a_payload_that_dies_with_exec_format_error_is_named_and_rolled_back(robot):
    robot.image("reg/ros/payload:mislabeled", "execformat")
    result = robot.apply("reg/ros/payload:mislabeled")
    assert result.returncode == 1
    assert (
        "robot-payload-payload-1 cannot run: exec format error: its program is not built for this robot's "
        "architecture (image reg/ros/payload:mislabeled)"
    ) in result.stderr
    assert "rolled back to r1 and it is running" in result.stderr
    assert robot.pointers() == ("r1", None)


# --- one structured result per run (issue 30, item 2) --------------------------------


def test_an_image_a_release_on_media_left_by_its_checked_tag_runs_by_that_tag_without_a_pull(robot):
    """The classic image store cannot find a loaded image by the release's
    digest; the pull agent tagged the id it checked media-sha256-<digest>
    (robotfleet/pull/robot/media.py): the release runs by that tag."""
    digest = "sha256:" + "e" * 64
    pinned, tag = f"reg/ros/payload:1.1@{digest}", f"reg/ros/payload:media-sha256-{'e' * 64}"
    robot.image(pinned, present=False, pull="fail")
    robot.image(tag)
    result = robot.apply(pinned)
    assert result.returncode == 0 and "is healthy" in result.stdout, result.stdout + result.stderr
    current, _ = robot.pointers()
    assert robot.releases.record(current)["images"][pinned]["pinned"] == tag
    assert [c["image"] for c in robot.state()["containers"].values()] == [tag]
    assert not [line for line in robot.state()["log"] if line.startswith("docker pull")]


def test_an_image_already_here_by_the_digest_its_reference_names_is_not_pulled_again(robot):
    """What a digest names never changes: a release on media loaded on the
    containerd store (or an earlier pull) left it, and a robot with no
    network runs it without waiting for a pull to fail."""
    pinned = "reg/ros/payload:1.1@sha256:" + "f" * 64
    for name in (pinned, "reg/ros/payload@sha256:" + "f" * 64):  # as Docker finds it, and as it runs
        robot.image(name, pull="fail")
    result = robot.apply(pinned)
    assert result.returncode == 0 and "is healthy" in result.stdout, result.stdout + result.stderr
    assert not [line for line in robot.state()["log"] if line.startswith("docker pull")]
