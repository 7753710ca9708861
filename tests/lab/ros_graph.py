"""The ROS graph of docs/guides/ros-payload.md (roscore, a talker, a
listener) as the lab deploys it: the guide's own fleet block, its registry
the lab's, on the lab's fleet file (inventories/lab.yaml).  Used by the
demo (tests/lab/demo.py) and tests/e2e/test_ros.py."""

from __future__ import annotations

import json
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[2]
GUIDE = ROOT / "docs" / "guides" / "ros-payload.md"
GUIDE_MARKER = "<!-- the ROS graph test_ros.py deploys -->"
RECORDER_MARKER = "<!-- the recorder test_ros.py adds -->"
GUIDE_REGISTRY = "registry.example.com/"
LAB_FLEET = ROOT / "inventories" / "lab.yaml"


def guide_vars(registry: str = "@registry@/", marker: str = GUIDE_MARKER) -> dict:
    """The guide's group vars for the graph (or the block after ``marker``), its images in ``registry``."""
    text = GUIDE.read_text()
    block = text[text.index(marker) :].split("```yaml\n", 1)[1].split("```", 1)[0]
    found = yaml.safe_load(block)["robots"]["vars"]
    return json.loads(json.dumps(found).replace(GUIDE_REGISTRY, registry))


def lab_vars(**more) -> dict:
    """The guide's vars as the lab's robots take them: their udev_sensors go to the talker."""
    graph = guide_vars()
    graph["payload_services"]["talker"]["devices"] = []
    return {**graph, **more}


def with_recorder(graph: dict, registry: str = "@registry@/") -> dict:
    """``graph``'s vars with the guide's recorder (section "Recording bags") added."""
    recorder = guide_vars(registry, RECORDER_MARKER)
    services = {**graph["payload_services"], **recorder.pop("payload_services")}
    return {**graph, **recorder, "payload_services": services}


def indented(mapping: dict, spaces: int) -> str:
    dumped = yaml.safe_dump(mapping, sort_keys=False, default_flow_style=False, width=1000)
    return "".join(" " * spaces + line + "\n" for line in dumped.splitlines())


def lab_fleet(hosts: dict[str, dict] | None = None) -> str:
    """inventories/lab.yaml with the graph: on every robot (the group's vars), or on ``hosts`` only
    (name -> more vars of that host)."""
    text = LAB_FLEET.read_text()
    if hosts is None:
        anchor = "robots:\n  vars:\n"
        return text.replace(anchor, anchor + indented(lab_vars(), 4), 1)
    for name, more in hosts.items():
        anchor = f"    {name}:\n"
        assert anchor in text, anchor
        text = text.replace(anchor, anchor + indented(lab_vars(**more), 6), 1)
    return text
