"""/etc/docker/daemon.json with a way back.

A new daemon.json is checked with ``dockerd --validate`` where dockerd has it
(Docker >= 23; older engines get a warning), but validation cannot see
conflicts with the unit's own flags (``hosts`` against ``-H fd://``) or values
dockerd refuses only at start.  The real guard is the restart: the previous
file is kept as daemon.json.previous, and if Docker is not active within
docker_restart_timeout seconds it is put back, Docker is restarted with it,
and the host fails with dockerd's reason.  Containers survive the restarts
where live-restore is on; elsewhere their restart policy brings them back.
"""

from __future__ import annotations

import base64
import shlex

from pyinfra import host

from robotfleet.host import operations
from robotfleet.host.snapshot import FileState

DAEMON_JSON = "/etc/docker/daemon.json"
PREVIOUS = DAEMON_JSON + ".previous"
# Exists from just before a new daemon.json is renamed in place until Docker
# runs with it: a dropped link or a power cut in between leaves it behind, and
# the next run restarts Docker (with the same way back) although the file
# already matches.
PENDING = DAEMON_JSON + ".pending"
# daemon.json may hold credentials (a proxy URL's password): root's alone,
# and so is the copy kept to go back to.
MODE = "600"
NO_VALIDATE_WARNING = (
    "warning: docker: this dockerd has no --validate (Docker < 23); the new daemon.json is checked "
    "by restarting Docker with it, and the previous file comes back if Docker does not start"
)


def write_script(dest: str = DAEMON_JSON, previous: str = PREVIOUS, pending: str = PENDING) -> str:
    """Install the daemon.json read (base64) from stdin: temp file, validated,
    fsynced, the old file kept as ``previous`` (or ``previous`` removed when
    there was none), then renamed in place."""
    q = shlex.quote
    return (
        f"dest={q(dest)}\n"
        f"prev={q(previous)}\n"
        f"pending={q(pending)}\n"
        'dir=$(dirname "$dest")\n'
        'mkdir -p "$dir" || exit 1\n'
        'tmp=$(mktemp "$dir/.robotprov.XXXXXX") || exit 1\n'
        'trap \'rm -f "$tmp" "$prev.tmp"\' EXIT\n'
        'base64 -d > "$tmp" && chown root:root "$tmp" && chmod 600 "$tmp" || exit 1\n'
        "if dockerd --help 2>&1 | grep -q -- '--validate'; then\n"
        '  out=$(dockerd --validate --config-file "$tmp" 2>&1) || '
        '{ echo "docker: dockerd rejects the new daemon.json: $(echo "$out" | tail -n 1); nothing changed" >&2; '
        "exit 1; }\n"
        "else\n"
        f"  echo {q(NO_VALIDATE_WARNING)} >&2\n"
        "fi\n"
        # A file still pending was never seen working: keep the one before it.
        'if [ -f "$pending" ]; then\n'
        "  :\n"
        'elif [ -L "$dest" ]; then\n'
        '  rm -f "$prev.tmp" && cp -P "$dest" "$prev.tmp" && mv -fT "$prev.tmp" "$prev" || exit 1\n'
        'elif [ -f "$dest" ]; then\n'
        # A new file made 0600 from the start (not cp -p of a looser file).
        '  rm -f "$prev.tmp" && (umask 077 && cat "$dest" > "$prev.tmp") && chown root:root "$prev.tmp" '
        '&& chmod 600 "$prev.tmp" && sync "$prev.tmp" && mv -fT "$prev.tmp" "$prev" || exit 1\n'
        "else\n"
        '  rm -f "$prev"\n'
        "fi\n"
        ': > "$pending" && sync "$tmp" && mv -fT "$tmp" "$dest" && sync "$dir" || exit 1\n'
        "trap - EXIT\n"
    )


def restart_script(
    action: str, timeout: int, dest: str = DAEMON_JSON, previous: str = PREVIOUS, pending: str = PENDING
) -> str:
    """``systemctl <action> docker``; if Docker is not active within
    ``timeout`` seconds, put the previous daemon.json back (or remove the new
    one when there was none), restart, and fail with dockerd's reason."""
    q = shlex.quote
    return (
        f"dest={q(dest)}\n"
        f"prev={q(previous)}\n"
        f"pending={q(pending)}\n"
        f"timeout={int(timeout)}\n"
        "docker_up() {\n"
        "  systemctl reset-failed docker.service 2>/dev/null\n"
        f'  timeout "$timeout" systemctl {action} docker.service >/dev/null 2>&1 '
        "&& systemctl is-active --quiet docker.service\n"
        "}\n"
        # journald may store dockerd's last line a moment after systemd records the failure (a loaded robot):
        # asked again for up to 5 s.
        "dockerd_said() {\n"
        "  for try in 1 2 3 4 5 6; do\n"
        '    said=$(journalctl -u docker.service SYSLOG_IDENTIFIER=dockerd --since "@$1" -o cat --no-pager 2>/dev/null'
        " | grep -iE 'daemon.json|failed to start|unable to|invalid|level=(error|fatal)' | tail -n 1 | cut -c1-300)\n"
        '    [ -n "$said" ] && { echo "$said"; return; }\n'
        '    [ "$try" -lt 6 ] && sleep 1\n'
        "  done\n"
        "  return 0\n"
        "}\n"
        "since=$(date +%s)\n"
        'docker_up && { rm -f "$pending"; exit 0; }\n'
        'reason=$(dockerd_said "$since")\n'
        'reason=${reason:-"not active after $timeout s at most (docker_restart_timeout)"}\n'
        'if [ -f "$prev" ]; then mv -fT "$prev" "$dest"; else rm -f "$dest"; fi\n'
        'rm -f "$pending"; sync "$(dirname "$dest")"\n'
        "since=$(date +%s)\n"
        "if docker_up; then\n"
        '  echo "docker: Docker did not start with the new daemon.json ($reason); '
        'the previous daemon.json is restored and Docker runs again" >&2\n'
        "else\n"
        '  again=$(dockerd_said "$since")\n'
        '  echo "docker: Docker did not start with the new daemon.json ($reason); the previous daemon.json is restored '
        'but Docker does not start with it either (${again:-not active after $timeout s at most})" >&2\n'
        "fi\n"
        "exit 1\n"
    )


def restarts_docker(content: str, current: FileState | None, pending: bool) -> bool:
    """Whether ``daemon_json`` will restart (or reload) Docker: the content
    differs, or an earlier run wrote it without applying it."""
    if current is not None and current.kind == "dir":
        return False
    same = current is not None and current.kind == "file" and current.sha256 == operations.sha256(content.encode())
    return pending or not same


def loose(state: FileState | None) -> bool:
    """A regular file others than root may read (an earlier version wrote 0644)."""
    return (
        state is not None
        and state.kind == "file"
        and (state.mode != MODE or (state.owner, state.group) != ("root", "root"))
    )


@operations.operation()
def daemon_json(
    content: str, current: FileState | None, action: str, timeout: int, pending: bool, previous: FileState | None = None
):
    """Make daemon.json hold ``content`` and apply it (``action``: restart or
    reload) with a way back; the owner and mode of the file and of its
    previous copy alone are fixed without touching Docker.  ``pending``: an
    earlier run wrote the file but may not have restarted Docker."""
    data = content.encode()
    if current is not None and current.kind == "dir":
        yield operations.refuse(f"{DAEMON_JSON} exists but is not a regular file; not replacing it")
        return
    # A symlink is replaced by a file (the rename replaces the link itself).
    same = current is not None and current.kind == "file" and current.sha256 == operations.sha256(data)
    if pending and same:
        yield operations.shell_with_warnings(restart_script(action, timeout))
        return
    if same:
        fix = [path for path, state in ((DAEMON_JSON, current), (PREVIOUS, previous)) if loose(state)]
        if not fix:
            host.noop(f"{DAEMON_JSON} is up to date")
            return
        yield operations.shell(" && ".join(f"chown root:root {path} && chmod 600 {path}" for path in fix))
        return
    if operations.planning_output_wanted() and host.state.config.DIFF:
        operations.show_diff(DAEMON_JSON, data, exists=current is not None and current.kind == "file")
    encoded = base64.encodebytes(data).decode().splitlines()
    yield operations.shell_with_warnings(write_script() + restart_script(action, timeout), stdin=encoded or [""])
