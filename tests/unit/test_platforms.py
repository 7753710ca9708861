"""Image platforms (roles/payload/payloadctl/platforms.py): architecture
names, the variant a robot gets from an index, the refusal lines."""

import pytest

from roles.payload.payloadctl import platforms


@pytest.mark.parametrize(
    "name, go",
    [
        ("amd64", "amd64"),
        ("x86_64", "amd64"),  # dpkg, uname
        ("arm64", "arm64"),
        ("aarch64", "arm64"),
        ("armhf", "arm"),
        ("armv7l", "arm"),
        ("ppc64el", "ppc64le"),
        ("riscv64", "riscv64"),
        ("mips64el", "mips64el"),
    ],
)
def test_architecture_names_are_dockers(name, go):
    assert platforms.go_arch(name) == go


def test_platforms_parse_and_print():
    assert platforms.parse("linux/arm64") == {"os": "linux", "architecture": "arm64"}
    assert platforms.parse("linux/arm/v7") == {"os": "linux", "architecture": "arm", "variant": "v7"}
    assert platforms.text({"os": "linux", "architecture": "arm64", "variant": "v8"}) == "linux/arm64/v8"
    for bad in ("arm64", "linux/", "Linux/ARM64", "linux/arm64/v8/x", "", None, 7):
        with pytest.raises(ValueError, match="expected os/architecture"):
            platforms.parse(bad)


def test_a_robot_runs_its_own_architecture_whatever_the_variant():
    assert platforms.matches("arm64", {"os": "linux", "architecture": "arm64", "variant": "v8"})
    assert platforms.matches("aarch64", {"os": "linux", "architecture": "arm64"})
    assert not platforms.matches("arm64", {"os": "linux", "architecture": "amd64"})
    assert not platforms.matches("amd64", {"os": "windows", "architecture": "amd64"})


INDEX = {
    "schemaVersion": 2,
    "mediaType": "application/vnd.oci.image.index.v1+json",
    "manifests": [
        {
            "mediaType": "application/vnd.oci.image.manifest.v1+json",
            "digest": "sha256:a",
            "size": 1,
            "platform": {"os": "linux", "architecture": "amd64"},
        },
        {
            "mediaType": "application/vnd.oci.image.manifest.v1+json",
            "digest": "sha256:v7",
            "size": 2,
            "platform": {"os": "linux", "architecture": "arm", "variant": "v7"},
        },
        {
            "mediaType": "application/vnd.oci.image.manifest.v1+json",
            "digest": "sha256:b",
            "size": 3,
            "platform": {"os": "linux", "architecture": "arm64", "variant": "v8"},
        },
        {
            "mediaType": "application/vnd.oci.image.manifest.v1+json",
            "digest": "sha256:att",
            "size": 4,
            "platform": {"os": "unknown", "architecture": "unknown"},
            "annotations": {
                "vnd.docker.reference.type": "attestation-manifest",
                "vnd.docker.reference.digest": "sha256:b",
            },
        },
    ],
}


def test_the_index_lists_image_variants_without_attestations():
    entries = platforms.index_entries(INDEX)
    assert [e["digest"] for e in entries] == ["sha256:a", "sha256:v7", "sha256:b"]
    assert platforms.index_entries({"manifests": None}) == []


def test_each_robot_gets_its_own_variant_of_the_index():
    entries = platforms.index_entries(INDEX)
    assert platforms.choose(entries, "arm64")["digest"] == "sha256:b"
    assert platforms.choose(entries, "amd64")["digest"] == "sha256:a"
    assert platforms.choose(entries, "armhf")["digest"] == "sha256:v7"
    assert platforms.choose(entries, "riscv64") is None


def test_arm64_prefers_v8_or_no_variant():
    entries = [
        {"digest": "sha256:v9", "platform": {"os": "linux", "architecture": "arm64", "variant": "v9"}},
        {"digest": "sha256:plain", "platform": {"os": "linux", "architecture": "arm64"}},
    ]
    assert platforms.choose(entries, "arm64")["digest"] == "sha256:plain"


def test_the_refusal_is_one_line_naming_robot_architecture_and_image():
    line = platforms.refusal("pi1", "aarch64", "reg/ros/payload:1.0", ["linux/amd64"])
    assert line == (
        "pi1 is linux/arm64 but image reg/ros/payload:1.0 is linux/amd64 only: refused before anything switched"
    )
    several = platforms.refusal("pi1", "arm64", "reg/x:1", ["linux/amd64", "linux/riscv64"], "in its registry")
    assert several == (
        "pi1 is linux/arm64 but image reg/x:1 is linux/amd64, linux/riscv64 "
        "(in its registry): refused before anything switched"
    )
    assert "\n" not in line and "\n" not in several
    assert platforms.pinned_refusal("robot1", "amd64", "camera", "linux/arm64") == (
        "robot1 is linux/amd64 but service camera pins platform linux/arm64: refused before anything switched"
    )


def test_exec_format_error_is_recognised_in_any_runc_wording():
    assert platforms.exec_format_error("exec /bin/sh: exec format error")
    assert platforms.exec_format_error("standard_init_linux.go:228: exec user process caused: exec format error")
    assert not platforms.exec_format_error("exec /bin/sh: no such file or directory")
    assert not platforms.exec_format_error(None)
