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
    "prefix",
    "ssh_key",
    "known_hosts",
    "ssh_user",
    "hosts",
    "services_host",
    "apt_proxy",
    "registry",
    "registry_local",
    "mirror_url",
    "mirror_dir",
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
        raise LabError(
            f"lab '{prefix}' is not up (no {path}): run `python3 -m tests.lab up --prefix {prefix}`"
        ) from None


def forget(prefix: str, root: Path = LAB_DIR) -> None:
    state_path(prefix, root).unlink(missing_ok=True)


# docker exec loses a command's output now and then, more often under load (moby/moby#27289,
# docker/docker-py#2042): exit 0 and no output.  The command's output goes to a file in the host's
# /dev/shm (tmpfs, any user may write) and is printed from it with an end mark; a stream without the
# mark is read again from the file (a read-only cat, safe to repeat), never by running the command again.
# Under load its stream has also come back missing its start, a frame header inside the text (the
# start mark catches that).
# The files are not removed by another docker exec (one more per command, the engine's CPU on every
# poll of a wait): once 64 are there, a command's script removes those older than a minute.
EXEC_START = "__lab_exec_start__\n"
PRINT_START = r"printf '%s\n' __lab_exec_start__"
EXEC_MARK = "\n__lab_exec_end__\n"
PRINT_MARK = r"printf '\n%s\n' __lab_exec_end__"
EXEC_KEEP = 64
EXEC_SCRIPT = (
    f'out=$1; shift; "$@" >"$out" 2>&1; rc=$?; {PRINT_START}; cat "$out"; {PRINT_MARK}; '
    f'set -- "${{out%/*}}"/lab-exec-*; [ "$#" -lt {EXEC_KEEP} ] || '
    'find "${out%/*}" -maxdepth 1 -name "lab-exec-*" -mmin +1 -delete 2>/dev/null; exit "$rc"'
)
EXEC_REREADS = 5


def exec_argv(cmd: str | list[str], out: str) -> list[str]:
    """The docker exec argv that runs ``cmd`` with its output in ``out``, then prints it and the mark."""
    command = ["sh", "-c", cmd] if isinstance(cmd, str) else list(cmd)
    return ["sh", "-c", EXEC_SCRIPT, "lab-exec", out, *command]


def exec_output(streamed: str) -> str | None:
    """The command's output from what the exec streamed, between its start and
    end marks; None when the stream lost part of it (either mark)."""
    if not streamed.startswith(EXEC_START):
        return None
    output, mark, rest = streamed[len(EXEC_START) :].rpartition(EXEC_MARK)
    return output if mark and not rest.strip() else None


def exec_in(prefix: str, host_name: str, cmd: str | list[str], user: str | None = None) -> tuple[int, str]:
    """Run `cmd` (a shell string or argv) in `<prefix>-<host_name>` via docker exec.

    Returns (exit code, stdout and stderr together).
    """
    return exec_container(client().containers.get(f"{prefix}-{host_name}"), cmd, user)


def exec_container(container, cmd: str | list[str], user: str | None = None) -> tuple[int, str]:
    """exec_in for a container object (any container with sh and /dev/shm)."""
    import uuid

    import docker.errors

    out = f"/dev/shm/lab-exec-{uuid.uuid4().hex}"
    code, streamed = container.exec_run(exec_argv(cmd, out), user=user or "")
    streamed = streamed.decode(errors="replace")
    output = exec_output(streamed)
    try:
        for _ in range(EXEC_REREADS if output is None else 0):
            _, again = container.exec_run(
                ["sh", "-c", f'{PRINT_START} && cat "$0" && {PRINT_MARK}', out], user=user or ""
            )
            output = exec_output(again.decode(errors="replace"))
            if output is not None:
                break
    except docker.errors.APIError:  # the command stopped its host (a power cut, a reboot): what came is all
        pass
    return code, streamed.removeprefix(EXEC_START) if output is None else output
