"""The snapshot's reading of the robot's containers (one probe): the
payload's own (state and status, as `docker ps` says them) and, where the
payload runs at boot, every container's identity for the takeover rule.

On the robot it is one Python process asking the engine's API
(docker_read.py); without python3, or where the docker CLI would ask
another engine (DOCKER_HOST, a context), the docker CLI answers instead,
in the same lines."""

from __future__ import annotations

import shlex
from pathlib import Path

PROBE = "payload_containers"
LABEL = "com.docker.compose.project"
_PROGRAM = (Path(__file__).parent / "docker_read.py").read_text()
_IDENTITY = (
    '{{json (printf "%s\\t%s\\t%s\\t%s\\t%v\\t%s" .Id .Name .Config.Image '
    f'(index .Config.Labels "{LABEL}") .State.Running .HostConfig.RestartPolicy.Name)}}}}'
)


def cli(project: str, foreign: bool) -> str:
    """The same lines from the docker CLI."""
    q = shlex.quote
    lines = [
        f"docker ps -a --filter label={LABEL}={q(project)} --format "
        f"{q('c' + chr(9) + '{{.State}}' + chr(9) + '{{.Status}}')}"
    ]
    if foreign:
        lines.append(f"docker ps -aq --no-trunc 2>/dev/null | xargs -r docker inspect -f {q('f' + chr(9) + _IDENTITY)}")
    return "; ".join(lines)


def probe(project: str, foreign: bool) -> str:
    q = shlex.quote
    args = q(project) + (" foreign" if foreign else "")
    return (
        f"if command -v python3 >/dev/null 2>&1 && python3 -I -S -c {q(_PROGRAM)} {args}; then :; "
        f"else {cli(project, foreign)}; fi"
    )


def part(output: str, kind: str) -> str:
    """The lines of one kind ("c": the payload's containers, "f": every
    container's identity), without their mark, as the old probes gave them."""
    mark = kind + "\t"
    return "".join(line[len(mark) :] + "\n" for line in output.splitlines() if line.startswith(mark))
