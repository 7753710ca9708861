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

from roles.hoststate import FileState

# How long apt and dpkg wait in all for a lock another process holds
# (unattended-upgrades at boot) when the host data does not say (apt_lock_timeout).
APT_LOCK_TIMEOUT = 300
# Exit status of a command that gave up waiting for an apt/dpkg lock.
LOCK_TIMED_OUT = 75
APT_GET = (
    "env DEBIAN_FRONTEND=noninteractive apt-get -y -q -o DPkg::Lock::Timeout=$(apt_lock_left)"
    " -o Dpkg::Options::=--force-confdef -o Dpkg::Options::=--force-confold"
)
APT_UPDATE = "apt-get -q -o DPkg::Lock::Timeout=$(apt_lock_left) -o Acquire::Retries=3 update"
DPKG_REPAIR = "env DEBIAN_FRONTEND=noninteractive dpkg --force-confdef --force-confold --configure -a"
# Shell functions behind the apt commands: apt_locked CMD... runs CMD again
# while it fails on an apt/dpkg lock (apt-get update and dpkg do not wait
# themselves), until $apt_deadline; then one line names the lock and its
# holder and it exits LOCK_TIMED_OUT.  A lock failure happens before apt or
# dpkg changes anything, so giving up leaves nothing half-installed.
APT_FUNCTIONS = r"""apt_lock_left() { echo $(( apt_deadline > $(date +%s) ? apt_deadline - $(date +%s) : 0 )); }
apt_locked() {
  log=$(mktemp)
  while :; do
    "$@" >"$log" 2>&1 && { rm -f "$log"; return 0; }
    rc=$?
    if ! grep -qE 'Could not get lock|Unable to acquire the dpkg frontend lock|Unable to lock|lock was locked by' "$log"; then
      cat "$log" >&2; rm -f "$log"; return $rc
    fi
    [ "$(date +%s)" -lt "$apt_deadline" ] && { sleep 2; continue; }
    lock=$(sed -n 's/.*Could not get lock \([^ ]*\)\. .*/\1/p; s/.*(\(\/var\/lib\/dpkg\/lock[^)]*\)).*/\1/p' "$log" | tail -n 1)
    holder=$(sed -n 's/.*held by process \([0-9][0-9]*\) (\([^)]*\)).*/\1 \2/p; s/.*locked by \([^ ]*\) process with pid \([0-9][0-9]*\).*/\2 \1/p' "$log" | tail -n 1)
    pid=${holder%% *}
    command=$(tr '\0' ' ' 2>/dev/null < "/proc/$pid/cmdline" | cut -c1-80)
    [ -n "$command" ] && holder="$pid $command"
    holder=${holder:+process ${holder%% *} (${holder#* })}
    echo "apt: ${lock:-the apt/dpkg lock} is held by ${holder:-another process} for more than $apt_lock_timeout s (apt_lock_timeout); nothing was installed, rerun when it is done" >&2
    rm -f "$log"; return @LOCK_TIMED_OUT@
  done
}
""".replace("@LOCK_TIMED_OUT@", str(LOCK_TIMED_OUT))


def apt_script(body: str, lock_timeout: int | None = None) -> str:
    """``body`` (using apt_locked) with the lock helpers and a deadline of
    ``lock_timeout`` seconds (default: the host's apt_lock_timeout)."""
    if lock_timeout is None:
        lock_timeout = host.data.get("apt_lock_timeout", APT_LOCK_TIMEOUT)
    return (
        f"apt_lock_timeout={int(lock_timeout)}\n"
        "apt_deadline=$(( $(date +%s) + apt_lock_timeout ))\n"
        f"{APT_FUNCTIONS}{body}\n"
    )


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
        key: value
        for key, value in (host.current_op_global_arguments or {}).items()
        if key in CONNECTOR_ARGUMENT_KEYS
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
):
    """Make ``path`` hold exactly ``content`` (checked with ``validate`` first,
    a shell command in which ``{}`` is the new file)."""
    if isinstance(content, str):
        content = content.encode()
    if current is not None and current.kind == "dir":
        yield refuse(f"{path} exists but is not a regular file; not replacing it")
        return
    # A symlink is replaced by the file (the rename replaces the link itself,
    # its target is left alone): chmod/chown would act on the target.
    if current is None or current.kind == "link" or current.sha256 != sha256(content):
        if planning_output_wanted() and host.state.config.DIFF:
            show_diff(path, content, exists=current is not None and current.kind == "file")
        yield write_file_command(path, content, mode, user, group, validate)
        return
    if _attributes_match(current, mode, user, group):
        host.noop(f"{path} is up to date")
        return
    yield shell(
        f"chown {shlex.quote(user)}:{shlex.quote(group)} {shlex.quote(path)}"
        f" && chmod {_mode(mode)} {shlex.quote(path)}"
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


def packages_missing(packages: list[str], installed: dict[str, str], versions: dict[str, str] | None = None):
    versions = versions or {}
    wanted = []
    for name in packages:
        version = versions.get(name)
        if name not in installed or (version and installed[name] != version):
            wanted.append(f"{name}={version}" if version else name)
    return wanted


@operation()
def apt_install(
    packages: list[str],
    installed: dict[str, str],
    versions: dict[str, str] | None = None,
    update_first: bool = False,
):
    """Install what is missing (or at another pinned version).  If apt cannot
    find a package with stale lists it refreshes them once and retries; a
    lock held past apt_lock_timeout stops it (no retry)."""
    wanted = packages_missing(packages, installed, versions)
    if not wanted:
        host.noop(f"{', '.join(packages)} installed")
        return
    names = " ".join(shlex.quote(p) for p in wanted)
    install = f"apt_locked {APT_GET} --allow-downgrades install {names}"
    update = f"apt_locked {APT_UPDATE}"
    if update_first:
        yield shell(apt_script(f"{update} && {install}"))
    else:
        yield shell(apt_script(
            f"{install} || {{ rc=$?; [ $rc -eq {LOCK_TIMED_OUT} ] && exit $rc; {update} && {install}; }}"
        ))


@operation()
def apt_remove(packages: list[str]):
    if not packages:
        host.noop("nothing to remove")
        return
    yield shell(apt_script(f"apt_locked {APT_GET} remove " + " ".join(shlex.quote(p) for p in packages)))


@operation(is_idempotent=False)
def apt_update():
    """Refresh the package lists (gated by the caller with ``_if``)."""
    yield shell(apt_script(f"apt_locked {APT_UPDATE}"))


def dpkg_interrupted(audit: str) -> bool:
    """Whether the snapshot's DPKG_AUDIT_PROBE output shows an interrupted
    dpkg run (a power cut or a dropped link during an install)."""
    return bool(audit.strip())


# Read in the host snapshot: dpkg's journal of an unfinished run (what apt
# calls "dpkg was interrupted") and packages left half-installed, unpacked
# or half-configured.  Empty on a healthy host.
DPKG_AUDIT_PROBE = (
    "ls /var/lib/dpkg/updates 2>/dev/null | grep -q . && echo 'dpkg journal not empty'; "
    "dpkg --audit 2>/dev/null | head -n 5"
)


@operation()
def dpkg_repair(audit: str):
    """Finish what an interrupted dpkg run left undone (dpkg --configure -a),
    so that the installs after it can run."""
    if not dpkg_interrupted(audit):
        host.noop("dpkg has no unfinished work")
        return
    yield shell(apt_script(
        f"apt_locked {DPKG_REPAIR} && apt_locked {APT_GET} --fix-broken install"
    ))


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
    return list(difflib.unified_diff(
        old.splitlines(), new.splitlines(), f"{path} (on the host)", f"{path} (planned)", lineterm=""
    ))


def show_diff(path: str, content: bytes, exists: bool) -> None:
    """Print what writing ``content`` to ``path`` changes (--diff).  The current
    content is fetched only here: for a file the snapshot found different."""
    old = ""
    if exists:
        lines = host.get_fact(FileContents, path=path) or []
        old = "".join(line + "\n" for line in lines)
    new = content.decode(errors="replace")
    host.log(f"{'Will modify' if exists else 'Will create'} {format_text(path, bold=True)}", logger.info)
    for line in unified_diff(path, old, new):
        colour = {"+": "green", "-": "red"}.get(line[:1]) if not line.startswith(("+++", "---")) else None
        logger.info("  %s", format_text(line, colour) if colour else line)


def fail_command(message: str) -> StringCommand:
    return shell(f"echo {shlex.quote(message)} >&2; exit 1")


def refuse(message: str) -> StringCommand:
    """What an operation yields when this host cannot reach its declared
    state: the command failing the host with ``message``.  While planning it
    also prints the reason and counts the host as failed, so ``--dry`` shows
    why and exits non-zero (a real run would fail the host at this step)."""
    state = host.state
    gated = bool((host.current_op_global_arguments or {}).get("_if"))
    if not state.is_executing and not gated:
        host.log_styled(message, log_func=logger.error, fg="red")
        state.failed_hosts.add(ctx_host.get())
    return fail_command(message)


@operation()
def fail(message: str):
    """Fail this host (only this host) with one clear line."""
    yield refuse(message)


@operation(is_idempotent=False)
def run(script: str):
    """A command gated by the caller (``_if``); always runs when reached."""
    yield shell(script)
