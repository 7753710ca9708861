"""What the pull agent keeps between wakes: agent-state.json in its state
directory (what it saw, applied and attempted, its last report and the
roles' last status).  Written whole or not at all; unreadable is empty."""

from __future__ import annotations

import json
from pathlib import Path

from robotfleet import atomicfile

STATE_FILE = "agent-state.json"


def load_state(state: Path) -> dict:
    try:
        found = json.loads((state / STATE_FILE).read_text())
        return found if isinstance(found, dict) else {}
    except (OSError, ValueError):
        return {}


def save_state(state: Path, data: dict) -> None:
    atomicfile.write(state / STATE_FILE, json.dumps(data, sort_keys=True, indent=1) + "\n")
