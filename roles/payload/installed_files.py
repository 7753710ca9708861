"""The payload's pieces on the robot: the release helper payloadctl (the
package roles/payload/payloadctl/ shipped as one zip application, so it is
written and replaced atomically like any file) and the systemd unit that
runs the current release at boot."""

from __future__ import annotations

import functools
import io
import zipfile
from pathlib import Path

import jinja2

HERE = Path(__file__).resolve().parent
PACKAGE = HERE / "payloadctl"
HELPER = "/usr/local/lib/robot-payload/payloadctl"
SHEBANG = b"#!/usr/bin/env python3\n"
MAIN = b"import sys\n\nfrom payloadctl.cli import main\n\nsys.exit(main())\n"
# A fixed time and mode in every entry: the same sources give the same bytes
# on every operator's machine, so a robot's helper is rewritten only when the
# code changed.
_STAMP = (1980, 1, 1, 0, 0, 0)


def unit_path(data) -> str:
    return f"/etc/systemd/system/{data.payload_name}.service"


def _entry(name: str) -> zipfile.ZipInfo:
    info = zipfile.ZipInfo(name, date_time=_STAMP)
    info.external_attr = 0o644 << 16
    info.compress_type = zipfile.ZIP_STORED  # zlib versions differ between machines; stored bytes do not
    return info


@functools.lru_cache(maxsize=1)
def helper_bytes() -> bytes:
    """payloadctl as a zip application: `python3 payloadctl <command>`."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        archive.writestr(_entry("__main__.py"), MAIN)
        for path in sorted(PACKAGE.glob("*.py")):
            archive.writestr(_entry(f"payloadctl/{path.name}"), path.read_bytes())
    return SHEBANG + buffer.getvalue()


@functools.lru_cache(maxsize=1)
def _unit_template() -> jinja2.Template:
    """Compiled once: compiling it for each robot cost more than the rest of its steps."""
    return jinja2.Template((HERE / "payload.service.j2").read_text(), keep_trailing_newline=True)


def unit_text(data, devices: list[str]) -> str:
    return _unit_template().render(
        name=data.payload_name,
        dir=data.payload_dir,
        helper=HELPER,
        devices=devices,
        device_wait=data.payload_device_wait,
    )
