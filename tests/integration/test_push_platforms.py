"""Push delivery sends the robot its own platform: the local engine's image
when it is built for the robot, else the robot's variant of the image's
multi-platform index read from its registry, only the layers the robot
lacks; an image with no variant for the robot is refused with one line.
A small registry answers here (the lab registry is the e2e tests'; the
local image chosen without a registry: tests/unit/test_status_and_push.py)."""

import json
import tarfile

from tests.integration.imagestore import digest
from tests.unit.samples import AMD64_LOCAL


def test_the_arm64_robot_gets_the_arm64_variant_of_the_index_from_the_registry(image_transfer, platform_registry):
    address, store, _ = platform_registry
    decision = image_transfer.choose_source(f"{address}/ros/payload:1.0", "", "pi1", "arm64", [], None, AMD64_LOCAL)
    kind, writer, (variant,), image_id = decision
    assert (kind, writer) == ("send", image_transfer.write_registry_archive)
    assert image_id == store.ids["arm64"] == variant["id"] and variant["platform"] == "linux/arm64"
    again = image_transfer.choose_source(
        f"{address}/ros/payload:1.0", store.ids["arm64"], "pi1", "arm64", [], None, None
    )
    assert again == ("noop", f"{address}/ros/payload:1.0 (linux/arm64) is already on the host")


def test_a_one_part_name_on_a_registry_other_than_docker_hub_is_read_under_that_name(image_transfer, platform_registry):
    """registry.lan:5000/payload:1 is /v2/payload/... on its registry (Docker
    adds library/ on Docker Hub only)."""
    address, store, _ = platform_registry
    kind, writer, (variant,), image_id = image_transfer.choose_source(
        f"{address}/payload:1.0", "", "pi1", "arm64", [], None, AMD64_LOCAL
    )
    assert (kind, writer) == ("send", image_transfer.write_registry_archive)
    assert image_id == store.ids["arm64"] == variant["id"]


def test_only_the_layers_the_robot_lacks_are_read_and_sent(image_transfer, platform_registry, tmp_path):
    address, store, fetched = platform_registry
    image = f"{address}/ros/payload:1.0"
    variant = image_transfer.registry_variant(image, "arm64", [], None)
    fetched.clear()
    report = {}
    # The robot has the amd64 image: the base layer is shared, the arm64 top is not.
    image_transfer.write_registry_archive(
        image, variant, str(tmp_path / "a.tar"), [store.diff_ids["amd64"]], report, [], None
    )
    with tarfile.open(tmp_path / "a.tar") as archive:
        names = archive.getnames()
        manifest = json.load(archive.extractfile("manifest.json"))[0]
        config = archive.extractfile(manifest["Config"]).read()
    assert digest(config) == store.ids["arm64"]  # docker load's image id is the registry's config digest
    assert manifest["RepoTags"] == [image] and len(manifest["Layers"]) == 2
    assert names == [manifest["Config"], manifest["Layers"][1], "manifest.json"]  # the base layer left out
    assert fetched == [json.loads(store.manifests["1.0-arm64"][1])["layers"][1]["digest"]]  # and not even downloaded
    assert report["layers"] == 2 and report["skipped"] == 1 and report["platform"] == "linux/arm64"
    blobs = [store.blobs[entry["digest"]] for entry in json.loads(store.manifests["1.0-arm64"][1])["layers"]]
    assert report["full"] == len(config) + sum(len(b) for b in blobs)
    assert report["sent"] == (tmp_path / "a.tar").stat().st_size


def test_an_image_without_the_robots_platform_is_refused_with_one_line(image_transfer, platform_registry):
    address, store, _ = platform_registry
    single = f"{address}/ros/payload:1.0-amd64"
    assert image_transfer.choose_source(single, "", "pi1", "arm64", [], None, None) == (
        "fail",
        f"payload: pi1 is linux/arm64 but image {single} is linux/amd64 only (in its registry): "
        "refused before anything switched",
    )
    kind, line = image_transfer.choose_source(f"{address}/ros/payload:1.0", "", "rv1", "riscv64", [], None, None)
    assert kind == "fail" and line == (
        f"payload: rv1 is linux/riscv64 but image {address}/ros/payload:1.0 is "
        "linux/amd64, linux/arm64 (in its registry): refused before anything switched"
    )


def test_a_local_image_of_another_platform_and_no_registry_is_refused_with_one_line(image_transfer):
    kind, line = image_transfer.choose_source("127.0.0.1:1/ros/payload:1.1", "", "pi1", "arm64", [], None, AMD64_LOCAL)
    assert kind == "fail" and "\n" not in line
    assert line.startswith(
        "payload: pi1 is linux/arm64 but image 127.0.0.1:1/ros/payload:1.1 is linux/amd64 "
        "only (in the local Docker engine; its registry: 127.0.0.1:1: GET "
    )
    assert line.endswith("): refused before anything switched")
    kind, line = image_transfer.choose_source("127.0.0.1:1/ros/payload:1.1", "", "pi1", "arm64", [], None, None)
    assert kind == "fail" and line.startswith(
        "payload_delivery push: 127.0.0.1:1/ros/payload:1.1 is neither in "
        "the local Docker engine nor readable from its registry ("
    )
