"""Pure parts of the status table and of layer-aware push delivery."""

import io
import re
import subprocess
import json
import tarfile

import pytest

from robotfleet import roster
from robotfleet.commands import status
from tests.unit.harness import merged
from roles.payload import push

A, B, C = ("sha256:" + c * 64 for c in "abc")


def test_layers_present_is_the_longest_shared_prefix():
    assert push.layers_present([A, B, C], []) == 0
    assert push.layers_present([A, B, C], [[A, C], [A, B]]) == 2
    assert push.layers_present([A, B], [[A, B, C]]) == 2
    assert push.layers_present([A, B], [[B, A]]) == 0  # same layers on another base are another chain


def test_layer_probe_output_is_parsed_line_by_line():
    output = json.dumps([A, B]) + "\n" + "garbage\n" + json.dumps([C]) + "\n"
    assert push.parse_layer_sets(output) == [[A, B], [C]]


def test_archive_leaves_out_layers_the_robot_has(tmp_path):
    """strip_layers on an archive laid out like `docker save` output."""
    saved = tmp_path / "saved.tar"
    with tarfile.open(saved, "w") as tar:
        def add(name, data):
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
        add("cfg.json", json.dumps({"rootfs": {"diff_ids": [A, B]}}).encode())
        add("l1/layer.tar", b"x" * 50000)
        add("l2/layer.tar", b"y" * 70000)
        add("manifest.json", json.dumps([{"Config": "cfg.json", "RepoTags": ["r/p:1"], "Layers": ["l1/layer.tar", "l2/layer.tar"]}]).encode())
    out = tmp_path / "sent.tar"
    report = push.strip_layers(str(saved), str(out), [[A]])
    with tarfile.open(out) as sent:
        assert sorted(sent.getnames()) == ["cfg.json", "l2/layer.tar", "manifest.json"]
        assert sent.extractfile("l2/layer.tar").read() == b"y" * 70000
    assert report["layers"] == 2 and report["skipped"] == 1 and report["sent"] < report["full"]


def roles():
    return roster.roles()


def test_status_rows_and_table():
    report = {
        "current": {"id": "r2", "state": "active", "activated": "2026-11-21T10:00:00Z",
                    "images": {"reg/p:1.1": {"id": "sha256:1", "pinned": "reg/p@sha256:" + "d" * 64}}},
        "previous": {"id": "r1"},
        "containers": [{"status": "running", "health": "healthy", "restarts": 0}],
        "update_lock": None,
    }
    rows = [status.row("robot1", roles(), {status.HOST_SECTION: "arm64\n", "docker": "26.1.5", "payload": json.dumps(report)}),
            status.row("robot2", roles(), None, "cannot connect")]
    assert rows[0]["image"] == "reg/p@sha256:" + "d" * 64 and rows[0]["previous"] == "r1"
    assert rows[1] == {"host": "robot2", "reachable": False, "error": "cannot connect"}
    text = status.table(rows, status.columns(roles())).splitlines()
    assert rows[0]["arch"] == "arm64"
    assert text[0].split() == ["HOST", "REACHABLE", "ARCH", "DOCKER", "RELEASE", "IMAGE", "STATE", "HEALTH", "PREVIOUS", "LAST", "DEPLOY", "LOCK", "GPU", "DRIVER", "GPU", "RUNTIME", "ROLLOUT"]
    assert text[1].split() == ["robot1", "yes", "arm64", "26.1.5", "r2", "reg/p@sha256:" + "d" * 12, "running", "healthy", "r1", "2026-11-21T10:00:00Z", "-", "-", "-", "-"]
    assert text[2].split()[:2] == ["robot2", "no"]


def test_status_shows_the_gpu_driver_version_and_the_runtime(tmp_path):
    """The GPU line comes from the real shell snippet (driver file from a
    setting); the runtime cell from Docker's runtimes list."""
    import subprocess

    driver = tmp_path / "version"
    driver.write_text("NVRM version: NVIDIA UNIX x86_64 Kernel Module  550.54.14  Thu Feb 22 01:44:30 UTC 2024\n")
    data = {"gpu_driver_version_file": str(driver)}
    command = status.status_command(roles(), merged("robots", data))
    out = subprocess.run(["sh", "-c", command], capture_output=True, text=True).stdout
    line = status.sections(out)["gpu"] + "\n"
    assert line.rstrip().endswith(("\tyes", "\tno"))
    cells = status.row("gpu1", roles(), {"docker": "26.1.5", "gpu": line.replace("\tno\n", "\tyes\n")})
    assert (cells["gpu_driver"], cells["gpu_runtime"]) == ("550.54.14", True)
    plain = status.row("r1", roles(), {"docker": "26.1.5", "gpu": "\tno\n"})
    assert (plain["gpu_driver"], plain["gpu_runtime"]) == (None, None)
    broken = status.row("r2", roles(), {"gpu": "NVRM version: NVIDIA UNIX x86_64 Kernel Module  550.54.14 x\tno\n"})
    assert broken["gpu_runtime"] is False
    text = status.table([cells], status.columns(roles()))
    assert text.splitlines()[1].split()[-3:] == ["550.54.14", "yes", "-"]  # then ROLLOUT


@pytest.mark.parametrize("payload", ["$(touch %s)", "`touch %s`", '"; touch %s; echo "', "'; touch %s; echo '"])
def test_a_hostile_image_name_in_the_push_log_is_never_run(tmp_path, payload):
    """Issue 17 item 5: the image name (and the rest of the log line) reaches
    the robot's shell as data.  The real command runs in a real sh; only
    `docker load` is a stand-in that reads the archive off stdin."""
    pwned = tmp_path / "pwned"
    image = "reg.lan/ros/payload:1.0" + payload % pwned
    archive = tmp_path / "image.tar.gz"
    archive.write_bytes(b"not really an image")
    bindir = tmp_path / "bin"
    bindir.mkdir()
    (bindir / "docker").write_text('#!/bin/sh\n[ "$1 $2" = "load -q" ] && exec cat >/dev/null\nexit 2\n')
    (bindir / "docker").chmod(0o755)
    log_dir = tmp_path / "payload dir"
    command = push.load_command(str(archive), log_dir=str(log_dir), image=image, image_id="sha256:" + "a" * 64,
                                figures={"sent": 10, "full": 20, "layers": 1, "skipped": 0})
    proc = subprocess.run(["sh", "-c", command.get_raw_value()], input="".join(command.connector_arguments["_stdin"]),
                          capture_output=True, text=True, env={"PATH": f"{bindir}:/usr/bin:/bin"}, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert not pwned.exists(), "the image name ran as a command"
    (line,) = (log_dir / "push.log").read_text().splitlines()
    stamp, logged = line.split(" ", 1)
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ", stamp)
    assert logged == f"{image} sha256:{'a' * 64} sent 10 of 20 bytes, 1 of 1 layers"


def test_status_reads_the_architecture_as_the_snapshot_does():
    """The engine's own part of the status command, run in a real sh on
    this machine (the e2e tests read an arm64 robot's)."""
    command = status.status_command(roles(), merged("robots", {}))
    out = subprocess.run(["sh", "-c", command], capture_output=True, text=True).stdout
    mine = subprocess.run(["dpkg", "--print-architecture"], capture_output=True, text=True).stdout.strip()
    assert mine and status.row("here", roles(), status.sections(out))["arch"] == mine
    assert status.row("old", roles(), {})["arch"] is None  # a host that did not answer the part: "-"
