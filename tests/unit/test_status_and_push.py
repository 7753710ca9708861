"""Pure parts of the status table and of layer-aware push delivery (their
shell snippets run in tests/integration/test_status_and_push.py)."""

import io
import json
import tarfile

from robotfleet import status_parts
from robotfleet.commands import status
from robotfleet.deploy_roles import roles
from roles.payload import image_transfer
from tests.unit.samples import AMD64_LOCAL

A, B, C = ("sha256:" + c * 64 for c in "abc")


def test_layers_present_is_the_longest_shared_prefix():
    assert image_transfer.layers_present([A, B, C], []) == 0
    assert image_transfer.layers_present([A, B, C], [[A, C], [A, B]]) == 2
    assert image_transfer.layers_present([A, B], [[A, B, C]]) == 2
    assert image_transfer.layers_present([A, B], [[B, A]]) == 0  # same layers on another base are another chain


def test_layer_probe_output_is_parsed_line_by_line():
    output = json.dumps([A, B]) + "\n" + "garbage\n" + json.dumps([C]) + "\n"
    assert image_transfer.parse_layer_sets(output) == [[A, B], [C]]


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
        add(
            "manifest.json",
            json.dumps(
                [{"Config": "cfg.json", "RepoTags": ["r/p:1"], "Layers": ["l1/layer.tar", "l2/layer.tar"]}]
            ).encode(),
        )
    out = tmp_path / "sent.tar"
    report = image_transfer.strip_layers(str(saved), str(out), [[A]])
    with tarfile.open(out) as sent:
        assert sorted(sent.getnames()) == ["cfg.json", "l2/layer.tar", "manifest.json"]
        assert sent.extractfile("l2/layer.tar").read() == b"y" * 70000
    assert report["layers"] == 2 and report["skipped"] == 1 and report["sent"] < report["full"]


def test_status_rows_and_table():
    report = {
        "current": {
            "id": "r2",
            "state": "active",
            "activated": "2026-11-21T10:00:00Z",
            "images": {"reg/p:1.1": {"id": "sha256:1", "pinned": "reg/p@sha256:" + "d" * 64}},
        },
        "previous": {"id": "r1"},
        "containers": [{"status": "running", "health": "healthy", "restarts": 0}],
        "update_lock": None,
    }
    rows = [
        status_parts.row(
            "robot1", roles(), {status_parts.HOST_SECTION: "arm64\n", "docker": "26.1.5", "payload": json.dumps(report)}
        ),
        status_parts.row("robot2", roles(), None, "cannot connect"),
    ]
    assert rows[0]["image"] == "reg/p:1.1@sha256:" + "d" * 64 and rows[0]["previous"] == "r1"  # the tag kept
    assert rows[1] == {"host": "robot2", "reachable": False, "error": "cannot connect"}
    text = status.table(rows, status_parts.columns(roles())).splitlines()
    assert rows[0]["arch"] == "arm64"
    assert text[0].split() == [
        "HOST",
        "REACHABLE",
        "ARCH",
        "DOCKER",
        "RELEASE",
        "IMAGE",
        "STATE",
        "HEALTH",
        "GRAPH",
        "PREVIOUS",
        "LAST",
        "DEPLOY",
        "LOCK",
        "GPU",
        "DRIVER",
        "GPU",
        "RUNTIME",
        "ROLLOUT",
    ]
    assert text[1].split() == [
        "robot1",
        "yes",
        "arm64",
        "26.1.5",
        "r2",
        "reg/p:1.1@sha256:" + "d" * 12,
        "running",
        "healthy",
        "-",
        "r1",
        "2026-11-21T10:00:00Z",
        "-",
        "-",
        "-",
        "-",
    ]
    assert text[2].split()[:4] == ["robot2", "no:", "cannot", "connect"]


def test_the_local_image_goes_when_it_is_built_for_the_robot():
    assert image_transfer.choose_source("r/p:1", "", "robot1", "amd64", [], None, AMD64_LOCAL)[:2] == (
        "send",
        image_transfer.write_archive,
    )
    assert image_transfer.choose_source("r/p:1", AMD64_LOCAL["id"], "robot1", "amd64", [], None, AMD64_LOCAL) == (
        "noop",
        "r/p:1 is already on the host",
    )
