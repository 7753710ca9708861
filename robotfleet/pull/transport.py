"""The robot's side of the fleet remote: git over SSH (or HTTPS), bounded
in time, with the bytes each exchange moved.

- ``fetch_releases``: the releases branch at depth 1 into the agent's own
  repository, checked out (the TUF client reads that directory); protocol
  v2 asks the server for that one branch only, so an idle check moves a
  few kilobytes whatever the size of the fleet.
- ``fetch_reports``: the reports of named robots (the waves before this
  robot's), each asked for by its own prefix.
- ``push_report``: this robot's report as a one-file commit, force-pushed
  to ``refs/reports/<robot>`` (the only ref the server lets it write).

The robot's own key is offered first, then a first-boot bundle's
enrollment key if it still has one; once the server accepts the robot's own
key, the enrollment key is deleted (it was single-use).  The git server's
host keys are pinned (StrictHostKeyChecking, under one alias, so a new
address or port does not matter).  Bytes are ssh's own count of what went
over the connection ("Transferred: sent N, received M bytes"; its debug
level also names the key the server accepted).
"""

from __future__ import annotations

import os
import re
import shlex
import signal
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from robotfleet.pull import layout

HOST_KEY_ALIAS = layout.HOST_KEY_ALIAS
LOCAL_BRANCH = "refs/remotes/fleet/releases"
_TRANSFERRED = re.compile(r"Transferred: sent (\d+), received (\d+) bytes")
_ACCEPTED = re.compile(r"Authenticated to .* using \"publickey\"|Server accepts key: (\S+)")
IDENTITY = {"GIT_AUTHOR_NAME": "robot-pull", "GIT_AUTHOR_EMAIL": "robot-pull@localhost",
            "GIT_COMMITTER_NAME": "robot-pull", "GIT_COMMITTER_EMAIL": "robot-pull@localhost"}


class TransportError(Exception):
    """The remote could not be reached or read (one line)."""


@dataclass
class Cost:
    """What the exchanges of one wake cost: bytes over the network and time."""

    sent: int = 0
    received: int = 0
    seconds: float = 0.0
    exchanges: list = field(default_factory=list)

    def add(self, what: str, sent: int, received: int, seconds: float) -> None:
        self.sent += sent
        self.received += received
        self.seconds += seconds
        self.exchanges.append({"what": what, "sent": sent, "received": received, "seconds": round(seconds, 3)})

    def as_dict(self) -> dict:
        return {"sent": self.sent, "received": self.received, "seconds": round(self.seconds, 3),
                "exchanges": self.exchanges}


def ssh_command(keys: list[str], known_hosts: str, log: str, timeout: int) -> str:
    """The ssh git runs: only these keys, the pinned host keys, no prompt."""
    parts = ["ssh", "-F", "/dev/null", "-o", "IdentitiesOnly=yes", "-o", "BatchMode=yes",
             "-o", "StrictHostKeyChecking=yes", "-o", f"UserKnownHostsFile={known_hosts}",
             "-o", f"HostKeyAlias={HOST_KEY_ALIAS}", "-o", f"ConnectTimeout={min(timeout, 30)}",
             "-o", "ServerAliveInterval=15", "-o", "ServerAliveCountMax=4",
             "-o", "LogLevel=DEBUG1", "-E", log]
    for key in keys:
        parts += ["-i", key]
    return " ".join(shlex.quote(p) for p in parts)


# What ssh and the server say of the cause, before git's own summary line.
_CAUSES = ("Permission denied", "Host key verification failed", "REMOTE HOST IDENTIFICATION HAS CHANGED",
           "Could not resolve", "Connection refused", "Connection timed out", "No route to host", "DENIED")
_SAYS = ("FATAL:", "fatal:", "ERROR:", "error:", "remote:")


def git_error(stderr: str, code: int) -> str:
    """The line of git's (or ssh's, or the server's) complaint that says why."""
    lines = [line.strip() for line in stderr.splitlines() if line.strip() and not line.startswith("hint:")]
    causes = [line for line in lines if any(cause in line for cause in _CAUSES)]
    said = [line for line in lines if line.startswith(_SAYS)]
    return (causes or said or lines or [f"git exited {code}"])[0][:300]


def read_ssh_log(text: str) -> tuple[int, int, str | None]:
    """(bytes sent, bytes received, the key the server accepted) from ssh's log."""
    sent = received = 0
    for match in _TRANSFERRED.finditer(text):
        sent += int(match.group(1))
        received += int(match.group(2))
    accepted = [m.group(1) for m in _ACCEPTED.finditer(text) if m.group(1)]
    return sent, received, accepted[-1] if accepted else None


class Remote:
    """The fleet remote as one robot reaches it."""

    def __init__(self, url: str, repo: str | Path, etc: str = layout.ETC, timeout: int = 300):
        self.url = url
        self.repo = Path(repo)
        self.etc = etc
        self.timeout = timeout
        self.cost = Cost()
        self.accepted_key: str | None = None

    # -- git with bounds ---------------------------------------------------

    def keys(self) -> list[str]:
        own, enroll = f"{self.etc}/id_ed25519", f"{self.etc}/enroll_ed25519"
        return [key for key in (own, enroll) if os.path.exists(key)]

    def _git(self, what: str, *args: str, network: bool = False, stdin: bytes | None = None,
             env: dict | None = None) -> bytes:
        environment = dict(os.environ, GIT_TERMINAL_PROMPT="0", LC_ALL="C", **IDENTITY, **(env or {}))
        log = None
        if network:
            fd, log = tempfile.mkstemp(prefix="robot-pull-ssh-", suffix=".log")
            os.close(fd)
            environment["GIT_SSH_COMMAND"] = ssh_command(self.keys(), f"{self.etc}/known_hosts", log, self.timeout)
        started = time.monotonic()
        try:
            process = subprocess.Popen(["git", "-C", str(self.repo), *args], stdin=subprocess.PIPE if stdin else None,
                                       stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=environment,
                                       start_new_session=True)
            try:
                out, err = process.communicate(stdin, timeout=self.timeout)
            except subprocess.TimeoutExpired:
                os.killpg(process.pid, signal.SIGKILL)
                process.communicate()
                raise TransportError(f"{what}: no answer from {self.url} within {self.timeout} s "
                                     "(pull_fetch_timeout)") from None
        except OSError as error:
            raise TransportError(f"{what}: cannot run git ({error})") from None
        finally:
            if log:
                try:
                    sent, received, accepted = read_ssh_log(Path(log).read_text(errors="replace"))
                finally:
                    os.unlink(log)
                self.cost.add(what, sent, received, time.monotonic() - started)
                self.accepted_key = accepted or self.accepted_key
        if process.returncode:
            raise TransportError(f"{what}: {git_error(err.decode(errors='replace'), process.returncode)}")
        return out

    def _init(self) -> None:
        if not (self.repo / ".git").is_dir():
            self.repo.mkdir(parents=True, exist_ok=True, mode=0o700)
            self._git("init", "init", "-q")
            # gc runs in this process (a oneshot unit would kill a detached
            # one), and what older fetches left goes at once.
            for key, value in (("gc.autoDetach", "false"), ("gc.pruneExpire", "now"), ("core.logAllRefUpdates", "false")):
                self._git("init", "config", key, value)

    # -- the releases branch -----------------------------------------------

    def fetch_releases(self, branch: str = layout.BRANCH) -> str:
        """Fetch the releases branch and check it out; its commit id."""
        self._init()
        self._git("fetch", "-c", "protocol.version=2", "fetch", "--quiet", "--no-tags", "--depth=1",
                  self.url, f"+refs/heads/{branch}:{LOCAL_BRANCH}", network=True)
        commit = self._git("fetch", "rev-parse", LOCAL_BRANCH).decode().strip()
        # Whatever is in the directory is made the commit's again (nothing
        # left over is read as part of the repository).
        self._git("checkout", "checkout", "-q", "--force", "--detach", commit)
        self._git("checkout", "clean", "-q", "-d", "-x", "--force")
        return commit

    # -- reports -----------------------------------------------------------

    def fetch_reports(self, robots: list[str]) -> dict[str, bytes]:
        """robot -> its report.json as the remote has it now (robots without one left out)."""
        if not robots:
            return {}
        self._init()
        specs = [f"+refs/reports/{robot}*:refs/fleet-reports/{robot}*" for robot in sorted(set(robots))]
        self._git("reports", "-c", "protocol.version=2", "fetch", "--quiet", "--no-tags", self.url, *specs,
                  network=True)
        return read_reports(self._git, "refs/fleet-reports/", set(robots))

    def push_report(self, robot: str, report: bytes) -> str:
        """Force-push ``report`` as refs/reports/<robot>; the commit id."""
        self._init()
        blob = self._git("report", "hash-object", "-w", "--stdin", stdin=report).decode().strip()
        tree = self._git("report", "mktree", stdin=f"100644 blob {blob}\treport.json\n".encode()).decode().strip()
        commit = self._git("report", "commit-tree", tree, "-m", f"report of {robot}").decode().strip()
        self._git("report", "push", "--quiet", "--force", self.url, f"{commit}:refs/reports/{robot}", network=True)
        return commit

    def retire_enrollment_key(self) -> bool:
        """Delete the enrollment key once the server took the robot's own key."""
        enroll = f"{self.etc}/enroll_ed25519"
        if self.accepted_key != f"{self.etc}/id_ed25519" or not os.path.exists(enroll):
            return False
        for path in (enroll, f"{enroll}.pub"):
            if os.path.exists(path):
                os.unlink(path)
        return True


def read_reports(git, prefix: str, wanted: set[str] | None = None) -> dict[str, bytes]:
    """name -> report.json of each commit under ``prefix`` (``git(what, *args, stdin=)``)."""
    listed = git("reports", "for-each-ref", "--format=%(refname) %(objectname)", prefix).decode().split("\n")
    refs = {}
    for line in filter(None, listed):
        name, _, commit = line.partition(" ")
        robot = name[len(prefix):]
        if wanted is None or robot in wanted:
            refs[robot] = commit
    if not refs:
        return {}
    batch = git("reports", "cat-file", "--batch",
                stdin="".join(f"{commit}:report.json\n" for commit in refs.values()).encode())
    found, at = {}, 0
    for robot in refs:
        end = batch.index(b"\n", at)
        header = batch[at:end].split()
        if len(header) == 3 and header[1] == b"blob":
            size = int(header[2])
            found[robot] = batch[end + 1:end + 1 + size]
            at = end + 1 + size + 1
        else:
            at = end + 1  # "<name> missing"
    return found
