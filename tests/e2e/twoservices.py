"""The two-service payload (ros/payload with a HEALTHCHECK, ros/driver
without, a secret file) as the fleet's all.vars: test_services.py deploys
it, test_rollout.py rolls it out."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

# On the operator's machine, outside the checkout (the fleet fixture writes it).
SECRET_FILE = Path(tempfile.gettempdir()) / f"robotfleet-e2e-{os.getpid()}-db_password"
SECRET = "db-pa55-e2e"


def two_services(payload: str = "1.1", driver: str = "1.0", driver_extra: str = "") -> str:
    """The fleet's all.vars for the two-service payload; its secret file is written here, since other
    modules (test_rollout) use these vars without this module's fixture."""
    SECRET_FILE.write_text(SECRET + "\n")
    return (
        "    payload_image: null\n"
        "    payload_services:\n"
        f'      payload: {{image: "@registry@/ros/payload:{payload}", ipc: host, cap_add: [NET_ADMIN], '
        "stop_grace_period: 3s}\n"
        f'      driver: {{image: "@registry@/ros/driver:{driver}", devices: [], tty: true, stop_grace_period: '
        f"3s{driver_extra}}}\n"
        f"    payload_secret_files: {{db_password: {SECRET_FILE}}}\n"
    )
