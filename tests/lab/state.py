"""What a running lab looks like: `.lab/<prefix>/state.json`, plus test helpers.

Keys (read by inventories/lab.py): prefix, ssh_key, known_hosts, ssh_user,
hosts [{name, group, arch, container, port}], services_host, apt_proxy, registry,
registry_local, mirror_url, mirror_dir; and "git" when the lab has its git
server {container, host, port, user, repo, known_hosts, host_keys}.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from .engine import LAB_DIR, LabError, client

STATE_KEYS = (
    "prefix", "ssh_key", "known_hosts", "ssh_user", "hosts", "services_host",
    "apt_proxy", "registry", "registry_local", "mirror_url", "mirror_dir",
)
# Only in a lab started with its git server (tests/lab/gitserver.py).
OPTIONAL_KEYS = ("git",)
HOST_KEYS = ("name", "group", "arch", "container", "port")


def lab_prefix() -> str:
    return os.environ.get("ROBOT_LAB_PREFIX", "lab")


def lab_dir(prefix: str, root: Path = LAB_DIR) -> Path:
    return root / prefix


def state_path(prefix: str, root: Path = LAB_DIR) -> Path:
    return lab_dir(prefix, root) / "state.json"


def save(state: dict, root: Path = LAB_DIR) -> Path:
    missing = [k for k in STATE_KEYS if k not in state]
    extra = [k for k in state if k not in STATE_KEYS + OPTIONAL_KEYS]
    if missing or extra:
        raise ValueError(f"lab state keys: missing {missing}, unexpected {extra}")
    path = state_path(state["prefix"], root)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(state, indent=2) + "\n")
    tmp.replace(path)
    return path


def load(prefix: str | None = None, root: Path = LAB_DIR) -> dict:
    prefix = prefix or lab_prefix()
    path = state_path(prefix, root)
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise LabError(f"lab '{prefix}' is not up (no {path}): "
                       f"run `python3 -m tests.lab up --prefix {prefix}`") from None


def forget(prefix: str, root: Path = LAB_DIR) -> None:
    state_path(prefix, root).unlink(missing_ok=True)


def exec_in(prefix: str, host_name: str, cmd: str | list[str],
            user: str | None = None) -> tuple[int, str]:
    """Run `cmd` (a shell string or argv) in `<prefix>-<host_name>` via docker exec.

    Returns (exit code, stdout and stderr together).
    """
    argv = ["sh", "-c", cmd] if isinstance(cmd, str) else list(cmd)
    container = client().containers.get(f"{prefix}-{host_name}")
    code, out = container.exec_run(argv, user=user or "")
    return code, out.decode(errors="replace")
