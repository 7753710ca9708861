"""Operations that compare desired state with the host snapshot.

Each one reads no fact of its own (the snapshot was taken once), does one
thing, and yields commands only for differences.  Files are written whole:
content goes over stdin into a temp file beside the target, is checked, then
renamed, so a dropped link never leaves a half-written file.
"""

from __future__ import annotations

import base64
import difflib
import hashlib
import shlex

from pyinfra import host, logger
from pyinfra.api import FunctionCommand, StringCommand, operation
from pyinfra.api.arguments import CONNECTOR_ARGUMENT_KEYS
from pyinfra.api.util import format_text, print_host_combined_output
from pyinfra.context import ctx_host
from pyinfra.facts.files import FileContents
from pyinfra.operations import server

from robotfleet import secrets
from robotfleet.checkers import one_line
from robotfleet.host.snapshot import FileState


def sha256(content: bytes) -> str:
    return hashlib.sha256(content).hexdigest()


def _mode(mode: str | int) -> str:
    return f"{int(str(mode), 8):o}"


def shell(script: str, stdin: str | list[str] | None = None) -> StringCommand:
    """A command running ``script`` with sh; sudo wraps it as a whole."""
    if stdin is None:
        return StringCommand("sh", "-c", shlex.quote(script))
    return StringCommand("sh", "-c", shlex.quote(script), _stdin=stdin)


WARNING = "warning: "


def shell_with_warnings(script: str, stdin: str | list[str] | None = None) -> FunctionCommand:
    """Like ``shell``, but the lines the script writes to stderr starting with
    "warning: " reach the operator even when it succeeds (pyinfra shows a
    command's output only when it fails).  Call it inside an operation."""
    command = shell(script, stdin)
    arguments = {
        key: value for key, value in (host.current_op_global_arguments or {}).items() if key in CONNECTOR_ARGUMENT_KEYS
    }
    arguments.update(command.connector_arguments)

    def run(state, host):
        status, output = host.run_shell_command(command, print_output=state.print_output, **arguments)
        for line in output.stderr_lines:
            if line.startswith(WARNING):
                host.log_styled(line, fg="yellow", log_func=logger.warning)
        if status is False and not state.print_output:
            print_host_combined_output(host, output)
        return status

    return FunctionCommand(run, (), {})


def write_file_command(path: str, content: bytes, mode: str, user: str, group: str, validate: str | None = None):
    """Atomic write: temp file in the same directory, checked, then renamed."""
    check = ""
    if validate:
        check = validate.replace("{}", '"$tmp"') + "\n"
    script = (
        "set -e\n"
        f"dest={shlex.quote(path)}\n"
        'dir=$(dirname "$dest")\n'
        'mkdir -p "$dir"\n'
        'tmp=$(mktemp "$dir/.robotprov.XXXXXX")\n'
        "trap 'rm -f \"$tmp\"' EXIT\n"
        'base64 -d > "$tmp"\n'
        f'chown {shlex.quote(user)}:{shlex.quote(group)} "$tmp"\n'
        f'chmod {_mode(mode)} "$tmp"\n'
        f"{check}"
        'mv -fT "$tmp" "$dest"\n'
        "trap - EXIT\n"
    )
    encoded = base64.encodebytes(content).decode().splitlines()
    return shell(script, stdin=encoded or [""])


def _attributes_match(current: FileState, mode, user: str, group: str) -> bool:
    return current.mode == _mode(mode) and (current.owner, current.group) == (user, group)


def file_matches(current: FileState | None, content: bytes, mode, user, group) -> bool:
    return (
        current is not None
        and current.kind == "file"
        and current.sha256 == sha256(content)
        and _attributes_match(current, mode, user, group)
    )


@operation()
def file(
    path: str,
    content: bytes | str,
    current: FileState | None,
    mode: str = "0644",
    user: str = "root",
    group: str = "root",
    validate: str | None = None,
    secret: bool = False,
):
    """Make ``path`` hold exactly ``content`` (checked with ``validate`` first,
    a shell command in which ``{}`` is the new file); a ``secret`` file's
    content is never shown, --diff says only that it changes."""
    if isinstance(content, str):
        content = content.encode()
    if current is not None and current.kind == "dir":
        yield refuse(f"{path} exists but is not a regular file; not replacing it")
        return
    # A symlink is replaced by the file (the rename replaces the link itself,
    # its target is left alone): chmod/chown would act on the target.
    if current is None or current.kind == "link" or current.sha256 != sha256(content):
        if planning_output_wanted() and host.state.config.DIFF:
            show_diff(path, content, exists=current is not None and current.kind == "file", secret=secret)
        yield write_file_command(path, content, mode, user, group, validate)
        return
    if _attributes_match(current, mode, user, group):
        host.noop(f"{path} is up to date")
        return
    yield shell(
        f"chown {shlex.quote(user)}:{shlex.quote(group)} {shlex.quote(path)} && chmod {_mode(mode)} {shlex.quote(path)}"
    )


def directory_command(path: str, mode: str, user: str, group: str) -> StringCommand:
    """install -d and chmod follow a symlink: refuse one, also if it appeared
    since the snapshot."""
    p = shlex.quote(path)
    return shell(
        f"if [ -L {p} ]; then echo {shlex.quote(_link_refusal(path))} >&2; exit 1; fi; "
        f"install -d -m {_mode(mode)} -o {shlex.quote(user)} -g {shlex.quote(group)} {p}"
        f" && chmod {_mode(mode)} {p}"
    )


def _link_refusal(path: str) -> str:
    return f"{path} is a symbolic link; not following it (make it a real directory)"


@operation()
def directory(path: str, current: FileState | None, mode: str = "0755", user: str = "root", group: str = "root"):
    if current is not None and current.kind == "link":
        yield refuse(_link_refusal(path))
        return
    if current is not None and current.kind != "dir":
        yield refuse(f"{path} exists but is not a directory")
        return
    if current is not None and _attributes_match(current, mode, user, group):
        host.noop(f"{path} is up to date")
        return
    yield directory_command(path, mode, user, group)


@operation()
def absent(paths: list[str], present: dict[str, FileState | None]):
    """Remove those of ``paths`` that exist."""
    existing = [p for p in paths if present.get(p) is not None]
    if not existing:
        host.noop("nothing to remove")
        return
    yield shell("rm -f " + " ".join(shlex.quote(p) for p in existing))


@operation()
def service(unit: str, enabled_now: bool, active_now: bool, enabled: bool = True, running: bool = True):
    commands = []
    if enabled and not enabled_now:
        commands.append(f"systemctl enable {shlex.quote(unit)}")
    if not enabled and enabled_now:
        commands.append(f"systemctl disable {shlex.quote(unit)}")
    if running and not active_now:
        commands.append(f"systemctl start {shlex.quote(unit)}")
    if not commands:
        host.noop(f"{unit} is as wanted")
        return
    yield shell(" && ".join(commands))


def planning_output_wanted() -> bool:
    """True once per operation: while planning (pyinfra's change detection),
    or while executing when planning was skipped (-y)."""
    state = host.state
    return not (state.is_executing and state.should_check_for_changes())


def unified_diff(path: str, old: str, new: str) -> list[str]:
    return list(
        difflib.unified_diff(
            old.splitlines(), new.splitlines(), f"{path} (on the host)", f"{path} (planned)", lineterm=""
        )
    )


def mask_credentials(text: str) -> str:
    """``text`` with this host's secrets and every URL password masked (robotfleet/secrets.py)."""
    return secrets.mask(text, secrets.of(host.name) if ctx_host.isset() else ())


def show_diff(path: str, content: bytes, exists: bool, secret: bool = False) -> None:
    """Print what writing ``content`` to ``path`` changes (--diff), with the
    host's secrets masked by value (and URL passwords by shape) and control
    characters escaped on both sides: a changed password shows as a changed
    line, never its value.  The current content is fetched only here: for a
    file the snapshot found different; a ``secret`` file's, never (nor its new content)."""
    what = f"{'Will modify' if exists else 'Will create'} {format_text(path, bold=True)}"
    if secret:
        host.log(f"{what} (a secret: its content is not shown)", logger.info)
        return
    old = ""
    if exists:
        lines = host.get_fact(FileContents, path=path) or []
        old = "".join(line + "\n" for line in lines)
    new = content.decode(errors="replace")
    host.log(what, logger.info)
    for line in unified_diff(path, old, new):
        line = one_line(mask_credentials(line))
        colour = {"+": "green", "-": "red"}.get(line[:1]) if not line.startswith(("+++", "---")) else None
        logger.info("  %s", format_text(line, colour) if colour else line)


def fail_command(message: str) -> StringCommand:
    return shell(f"echo {shlex.quote(one_line(message))} >&2; exit 1")


def refuse(message: str) -> StringCommand:
    """What an operation yields when this host cannot reach its declared
    state: the command failing the host with ``message``.  While planning it
    also prints the reason and counts the host as failed, so ``--dry`` shows
    why and exits non-zero (a real run would fail the host at this step)."""
    state = host.state
    gated = bool((host.current_op_global_arguments or {}).get("_if"))
    if not state.is_executing and not gated:
        host.log_styled(one_line(message), log_func=logger.error, fg="red")
        state.failed_hosts.add(ctx_host.get())
    return fail_command(message)


@operation()
def fail(message: str):
    """Fail this host (only this host) with one clear line."""
    yield refuse(message)


def run(script: str, **arguments):
    """A command gated by the caller (``_if``); always runs when reached.
    pyinfra's own server.shell: it reads no fact, so it costs no round trip
    of its own, and a converged rerun (gate closed) sends nothing."""
    return server.shell(commands=[script], **arguments)
