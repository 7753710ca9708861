"""apt and dpkg on a host: installs that wait (boundedly) for a lock another
process holds, and an interrupted dpkg run finished first."""

from __future__ import annotations

import shlex

from pyinfra import host
from pyinfra.api import operation

from robotfleet.host.operations import shell

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
    if ! grep -qE 'Could not get lock|Unable to acquire the dpkg frontend lock|Unable to lock|lock was locked by' \
        "$log"; then
      cat "$log" >&2; rm -f "$log"; return $rc
    fi
    [ "$(date +%s)" -lt "$apt_deadline" ] && { sleep 2; continue; }
    lock=$(sed -n -e 's/.*Could not get lock \([^ ]*\)\. .*/\1/p' \
        -e 's/.*(\(\/var\/lib\/dpkg\/lock[^)]*\)).*/\1/p' "$log" | tail -n 1)
    holder=$(sed -n -e 's/.*held by process \([0-9][0-9]*\) (\([^)]*\)).*/\1 \2/p' \
        -e 's/.*locked by \([^ ]*\) process with pid \([0-9][0-9]*\).*/\2 \1/p' "$log" | tail -n 1)
    pid=${holder%% *}
    command=$(tr '\0' ' ' 2>/dev/null < "/proc/$pid/cmdline" | cut -c1-80)
    [ -n "$command" ] && holder="$pid $command"
    holder=${holder:+process ${holder%% *} (${holder#* })}
    echo "apt: ${lock:-the apt/dpkg lock} is held by ${holder:-another process} for more than $apt_lock_timeout s" \
        "(apt_lock_timeout); nothing was installed, rerun when it is done" >&2
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
        yield shell(
            apt_script(f"{install} || {{ rc=$?; [ $rc -eq {LOCK_TIMED_OUT} ] && exit $rc; {update} && {install}; }}")
        )


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


# Packages dpkg --audit has nothing to say about: "ok" (not reinstreq) and
# installed, not installed or config-files only; installed ones of the
# native architecture (or all) with their list and md5sums files (named
# pkg:arch for Multi-Arch: same in dpkg's multiarch database).  Exit 0
# only when every package is so (see dpkg's src/main/enquiry.c, audit()).
# Its first input is the names in dpkg's info directory (`ls -f`), the
# second the status file.
_AUDIT_CLEAN_AWK = r"""FNR == NR {info[$0] = 1; next}
FNR == 1 {f = ""; getline f < (d "/info/format")}
function check() {
  if (p != "") {
    split(s, w, " ")
    if (w[2] != "ok" || (w[3] != "installed" && w[3] != "not-installed" && w[3] != "config-files")) bad = 1
    else if (w[3] == "installed") {
      if (r != "all" && r != a) bad = 1
      n = m == "same" && f == "1" ? p ":" r : p
      if (!((n ".list") in info) || !((n ".md5sums") in info)) bad = 1
    }
  }
  p = s = r = m = ""
}
/^Package: / {p = substr($0, 10)}
/^Status: / {s = substr($0, 9)}
/^Architecture: / {r = substr($0, 15)}
/^Multi-Arch: / {m = substr($0, 13)}
/^$/ {check()}
END {check(); exit bad || NR == FNR}"""


def dpkg_audit_probe(admindir: str = "/var/lib/dpkg") -> str:
    """Read in the host snapshot: dpkg's journal of an unfinished run (what
    apt calls "dpkg was interrupted") and packages left half-installed,
    unpacked or half-configured (dpkg --audit's first lines).  Empty on a
    healthy host.  dpkg --audit itself only runs where the journal or the
    status file (read with awk) shows something it would report."""
    d = shlex.quote(admindir)
    return (
        f'j=; for f in {d}/updates/*; do [ -e "$f" ] && j=1; done; '
        "[ -n \"$j\" ] && echo 'dpkg journal not empty'; "
        f'if [ -n "$j" ] || ! ls -f {d}/info | awk -v d={d} -v a="$(dpkg --print-architecture 2>/dev/null)" '
        f"{shlex.quote(_AUDIT_CLEAN_AWK)} - {d}/status 2>/dev/null; then "
        f"dpkg --admindir={d} --audit 2>/dev/null | head -n 5; fi"
    )


DPKG_AUDIT_PROBE = dpkg_audit_probe()


@operation()
def dpkg_repair(audit: str):
    """Finish what an interrupted dpkg run left undone (dpkg --configure -a),
    so that the installs after it can run."""
    if not dpkg_interrupted(audit):
        host.noop("dpkg has no unfinished work")
        return
    yield shell(apt_script(f"apt_locked {DPKG_REPAIR} && apt_locked {APT_GET} --fix-broken install"))
