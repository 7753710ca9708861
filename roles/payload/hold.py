"""The payload's part in a pull robot's converge run: the agent holds the
apply lock for the whole run with `payloadctl hold`, and the deploy's own
apply joins it with the token (payload_lock_token) instead of waiting."""

from __future__ import annotations

import os

from robotfleet.role import HoldPart
from roles.payload.installed_files import HELPER


def hold_command(data, token_file: str) -> list[str]:
    """`payloadctl hold ... --` on this robot; [] before payloadctl is
    installed (the first deploy installs it; nothing can hold the lock yet)."""
    if not os.path.exists(HELPER):
        return []
    return [
        "/usr/bin/python3",
        HELPER,
        "hold",
        "--dir",
        data.payload_dir,
        "--token-file",
        token_file,
        "--by",
        "pull agent",
        "--",
    ]


HOLD = HoldPart(command=hold_command, setting="payload_lock_token")
