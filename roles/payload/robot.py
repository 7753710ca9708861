"""The payload's pieces on the robot: the release helper payloadctl and
the systemd unit that runs the current release at boot."""

from __future__ import annotations

from pathlib import Path

import jinja2

HERE = Path(__file__).resolve().parent
HELPER = "/usr/local/lib/robot-payload/payloadctl"


def unit_path(data) -> str:
    return f"/etc/systemd/system/{data.payload_name}.service"


def helper_text() -> str:
    return (HERE / "payloadctl.py").read_text()


def unit_text(data, devices: list[str]) -> str:
    template = jinja2.Template((HERE / "payload.service.j2").read_text(), keep_trailing_newline=True)
    return template.render(
        name=data.payload_name,
        dir=data.payload_dir,
        helper=HELPER,
        devices=devices,
        device_wait=data.payload_device_wait,
    )
