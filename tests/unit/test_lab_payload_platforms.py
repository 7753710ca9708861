"""The lab's multi-platform payload (tests/lab/payload_platforms.py): the
pure parts; the registry writes run in every lab up."""

import io
import json
import tarfile

import pytest


@pytest.fixture(autouse=True)
def _module():
    # Imported when a test runs, like the other lab modules (tests/unit/conftest.py).
    global pp
    pp = __import__("tests.lab.payload_platforms", fromlist=["x"])


CONFIG = {
    "architecture": "amd64",
    "os": "linux",
    "config": {"Labels": {"org.opencontainers.image.version": "1.0"}, "Cmd": ["/bin/sh", "/payload.sh"]},
    "rootfs": {"type": "layers", "diff_ids": ["sha256:" + "a" * 64, "sha256:" + "b" * 64]},
}


def test_a_layer_is_the_same_bytes_for_the_same_files(tmp_path):
    for name in ("one", "two"):
        root = tmp_path / name
        (root / "bin").mkdir(parents=True)
        (root / "bin" / "busybox").write_bytes(b"\x7fELF...")
        (root / "bin" / "busybox").chmod(0o755)
        (root / "bin" / "sh").symlink_to("busybox")
    first, second = pp.layer_tar(tmp_path / "one"), pp.layer_tar(tmp_path / "two")
    assert first == second
    with tarfile.open(fileobj=io.BytesIO(first)) as tar:
        members = {m.name: m for m in tar.getmembers()}
    assert sorted(members) == ["bin", "bin/busybox", "bin/sh"]
    assert members["bin/sh"].issym() and members["bin/sh"].linkname == "busybox"
    busybox = members["bin/busybox"]
    assert busybox.mode == 0o755 and busybox.uid == 0 and busybox.mtime == 0


def test_an_elf_program_for_no_machine():
    elf = b"\x7fELF" + bytes(14) + b"\x3e\x00" + b"rest"
    broken = pp.without_machine(elf)
    assert broken[18:20] == b"\x00\x00" and len(broken) == len(elf) and broken[20:] == b"rest"
    with pytest.raises(ValueError):
        pp.without_machine(b"#!/bin/sh\n")


def test_the_arm64_config_is_the_amd64_one_with_its_own_rootfs_and_platform():
    arm64 = pp.variant_config(CONFIG, "sha256:" + "c" * 64, pp.PLATFORMS["arm64"])
    assert (arm64["architecture"], arm64["os"], arm64["variant"]) == ("arm64", "linux", "v8")
    assert arm64["rootfs"]["diff_ids"] == ["sha256:" + "c" * 64, "sha256:" + "b" * 64]  # the scripts layer is shared
    assert arm64["config"] == CONFIG["config"] and CONFIG["architecture"] == "amd64"  # the original is untouched
    broken = pp.variant_config(CONFIG, "sha256:" + "d" * 64, pp.PLATFORMS["amd64"], "1.3-exec-format")
    assert "variant" not in broken
    assert broken["config"]["Labels"]["org.opencontainers.image.version"] == "1.3-exec-format"


def test_the_index_names_each_manifest_and_its_platform():
    manifest_type = "application/vnd.docker.distribution.manifest.v2+json"
    index = json.loads(
        pp.index_document(
            [
                (manifest_type, b"{}", "sha256:1", pp.PLATFORMS["amd64"]),
                (manifest_type, b"{ }", "sha256:2", pp.PLATFORMS["arm64"]),
            ]
        )
    )
    assert index["mediaType"] == pp.OCI_INDEX and index["schemaVersion"] == 2
    assert [(m["digest"], m["size"], m["platform"]["architecture"]) for m in index["manifests"]] == [
        ("sha256:1", 2, "amd64"),
        ("sha256:2", 3, "arm64"),
    ]


def test_a_health_cadence_replaces_the_timings_and_keeps_the_check():
    config = {"config": {"Healthcheck": {"Test": ["CMD", "/bin/sh", "/healthcheck.sh"], "Interval": 2, "Retries": 3}}}
    faster = pp.with_health_cadence(config, pp.HEALTH_CADENCE)
    assert faster["config"]["Healthcheck"] == {
        "Test": ["CMD", "/bin/sh", "/healthcheck.sh"],
        "Retries": 3,
        **pp.HEALTH_CADENCE,
    }
    assert config["config"]["Healthcheck"]["Interval"] == 2  # the original is untouched
    assert pp.HEALTH_CADENCE["StartInterval"] == 10**9 and pp.HEALTH_CADENCE["Interval"] == 30 * 10**9
    assert pp.with_health_cadence(CONFIG, pp.HEALTH_CADENCE)["config"] == CONFIG["config"]  # no HEALTHCHECK: as it was
