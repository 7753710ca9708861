"""A lab container's sshd (hosts, the git server): waiting until it runs,
with the host keys it made."""

from __future__ import annotations

import time

from .engine import LabError

PROBE = "systemctl is-active --quiet ssh.service && cat /etc/ssh/ssh_host_*_key.pub"


def wait_for_host_keys(container, timeout: float) -> list[str]:
    """The container's public host keys once its sshd runs."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        container.reload()
        if container.status != "running":
            raise LabError(f"{container.name} is {container.status}; see `docker logs {container.name}`")
        code, out = container.exec_run(["sh", "-c", PROBE])
        keys = [line for line in out.decode().splitlines() if line.strip()]
        if code == 0 and keys:
            return keys
        time.sleep(0.5)
    raise LabError(
        f"{container.name}: sshd not running after {timeout}s (docker exec {container.name} systemctl status ssh)"
    )
