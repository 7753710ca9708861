"""The status command's shell snippets and the push log's command run by a
real sh on this machine (tests/unit/test_status_and_push.py: the pure parts)."""

import re

import pytest

from robotfleet import status_parts
from robotfleet.commands import status
from robotfleet.deploy_roles import roles
from roles.payload import image_transfer
from tests.fixtures import run_command, sh
from tests.unit.harness import merged


def test_status_shows_the_gpu_driver_version_and_the_runtime(tmp_path):
    """The GPU line comes from the real shell snippet (driver file from a
    setting); the runtime cell from Docker's runtimes list."""
    driver = tmp_path / "version"
    driver.write_text("NVRM version: NVIDIA UNIX x86_64 Kernel Module  550.54.14  Thu Feb 22 01:44:30 UTC 2024\n")
    data = {"gpu_driver_version_file": str(driver)}
    command = status_parts.status_command(roles(), merged("robots", data))
    out = sh(command).stdout
    line = status_parts.sections(out)["gpu"] + "\n"
    assert line.rstrip().endswith(("\tyes", "\tno"))
    cells = status_parts.row("gpu1", roles(), {"docker": "26.1.5", "gpu": line.replace("\tno\n", "\tyes\n")})
    assert (cells["gpu_driver"], cells["gpu_runtime"]) == ("550.54.14", True)
    plain = status_parts.row("r1", roles(), {"docker": "26.1.5", "gpu": "\tno\n"})
    assert (plain["gpu_driver"], plain["gpu_runtime"]) == (None, None)
    broken = status_parts.row(
        "r2", roles(), {"gpu": "NVRM version: NVIDIA UNIX x86_64 Kernel Module  550.54.14 x\tno\n"}
    )
    assert broken["gpu_runtime"] is False
    text = status.table([cells], status_parts.columns(roles()))
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
    command = image_transfer.load_command(
        str(archive),
        log_dir=str(log_dir),
        image=image,
        image_id="sha256:" + "a" * 64,
        figures={"sent": 10, "full": 20, "layers": 1, "skipped": 0},
    )
    proc = run_command(command, env={"PATH": f"{bindir}:/usr/bin:/bin"})
    assert proc.returncode == 0, proc.stderr
    assert not pwned.exists(), "the image name ran as a command"
    (line,) = (log_dir / "push.log").read_text().splitlines()
    stamp, logged = line.split(" ", 1)
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ", stamp)
    assert logged == f"{image} sha256:{'a' * 64} sent 10 of 20 bytes, 1 of 1 layers"


def test_status_reads_the_architecture_as_the_snapshot_does():
    """The engine's own part of the status command, run in a real sh on
    this machine (the e2e tests read an arm64 robot's)."""
    command = status_parts.status_command(roles(), merged("robots", {}))
    out = sh(command).stdout
    mine = sh("dpkg --print-architecture").stdout.strip()
    assert mine and status_parts.row("here", roles(), status_parts.sections(out))["arch"] == mine
    assert status_parts.row("old", roles(), {})["arch"] is None  # a host that did not answer the part: "-"
