"""Where the release repository is published.

- The releases remote (the one the fleet names, robotfleet/commands/
  releasesremote.py; never the deploy repository's origin by default): its
  branch ``robotfleet/releases``, an orphan branch holding only
  the TUF repository (metadata/, targets/).  Publishing works in a private
  clone (``<checkout>/.robotfleet/releases``, or ROBOTFLEET_RELEASES_CLONE),
  reset to the remote's branch, then commits and pushes fast-forward: a
  push that the remote refuses because someone else published meanwhile is
  one line, "fetch again and rerun", never a force push.
- A directory (``--to-dir``) served as it is over static HTTPS.

Git's transport is not the trust (the TUF signatures are); it only moves
the files.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

from robotfleet import keepalive

BRANCH = "robotfleet/releases"
CLONE_ENV = "ROBOTFLEET_RELEASES_CLONE"
GIT_TIMEOUT = 600
IDENTITY = ["-c", "user.name=robotfleet publish", "-c", "user.email=robotfleet@localhost", "-c", "commit.gpgsign=false"]


class ChannelError(Exception):
    """The channel cannot be read or written; the message is one line."""


def _git(where: Path, *args: str, check: bool = True) -> subprocess.CompletedProcess:
    try:
        done = subprocess.run(
            ["git", "-C", str(where), *args],
            capture_output=True,
            text=True,
            timeout=GIT_TIMEOUT,
            check=False,
            env=keepalive.git_environment({**os.environ, "GIT_TERMINAL_PROMPT": "0"}, str(where)),
        )
    except (OSError, subprocess.TimeoutExpired) as error:
        raise ChannelError(f"git {args[0]}: {error}") from None
    if check and done.returncode:
        raise ChannelError(f"git {' '.join(a for a in args[:2] if not a.startswith('-c'))}: {why(done)}")
    return done


def why(done: subprocess.CompletedProcess) -> str:
    """What a failed git said, in its one line that says why: its first fatal: or error: line (git follows it
    with advice such as "and the repository exists."), else its last line."""
    said = [line.strip() for line in done.stderr.splitlines() if line.strip()]
    cause = next((line for line in said if line.startswith(("fatal:", "error:"))), said[-1] if said else None)
    if cause is None:
        return f"exit status {done.returncode}"
    return cause.split(":", 1)[1].strip() if cause.startswith(("fatal:", "error:")) else cause


def remote_url(checkout, remote: str) -> str:
    """``remote`` as a URL: a remote's name in the checkout, or already a URL or path."""
    done = _git(Path(checkout), "remote", "get-url", remote, check=False)
    if done.returncode == 0:
        return done.stdout.strip()
    if "/" in remote or ":" in remote:
        return remote
    raise ChannelError(f"{remote}: no such remote in {checkout}; give one of its remotes (git remote -v) or a URL.")


class GitChannel:
    """The fleet remote's releases branch, through a private clone."""

    def __init__(self, checkout, remote: str, clone=None):
        self.checkout = Path(checkout)
        self.url = remote_url(self.checkout, remote)
        self.clone = Path(clone or os.environ.get(CLONE_ENV) or self.checkout / ".robotfleet" / "releases")
        self.base: str | None = None  # the commit the branch was at when opened (None: new branch)

    def open(self) -> Path:
        """The repository directory, as the remote's branch has it now (empty if the branch is new)."""
        if not (self.clone / ".git").exists():
            if self.clone.exists():
                shutil.rmtree(self.clone)
            self.clone.mkdir(parents=True)
            _git(self.clone, "init", "--quiet")
        _git(self.clone, "remote", "remove", "fleet", check=False)
        _git(self.clone, "remote", "add", "fleet", self.url)
        _git(self.clone, "config", "core.symlinks", "false")  # a link on the branch is checked out as a file
        fetched = _git(
            self.clone,
            "fetch",
            "--quiet",
            "--no-tags",
            "fleet",
            f"+refs/heads/{BRANCH}:refs/remotes/fleet/{BRANCH}",
            check=False,
        )
        if fetched.returncode == 0:
            self.base = _git(self.clone, "rev-parse", f"refs/remotes/fleet/{BRANCH}").stdout.strip()
            _git(self.clone, "checkout", "--quiet", "--force", "-B", BRANCH, self.base)
        else:
            listed = _git(self.clone, "ls-remote", "--heads", "fleet", BRANCH, check=False)
            if listed.returncode:
                raise ChannelError(
                    f"cannot read the releases remote {self.url}: {why(listed)}; check its URL "
                    "(--remote, git config robotfleet.remote or the robots' pull_remote) and that "
                    "you may read it."
                )
            if listed.stdout.strip():
                raise ChannelError(f"git fetch {self.url} {BRANCH}: {why(fetched)}")
            self.base = None  # a new orphan branch (a failed earlier attempt's local one is dropped)
            _git(self.clone, "symbolic-ref", "HEAD", f"refs/heads/{BRANCH}")
            _git(self.clone, "update-ref", "-d", f"refs/heads/{BRANCH}")
            _git(self.clone, "read-tree", "--empty")
        _git(self.clone, "clean", "-q", "-d", "-x", "--force")
        return self.clone

    def push(self, message: str) -> str:
        """Commit the repository as it is now and push it fast-forward; the commit id."""
        _git(self.clone, "add", "--all", ".")
        _git(self.clone, *IDENTITY, "commit", "--quiet", "--allow-empty", "-m", message)
        head = _git(self.clone, "rev-parse", "HEAD").stdout.strip()
        pushed = _git(self.clone, "push", "--quiet", "fleet", f"HEAD:refs/heads/{BRANCH}", check=False)
        if pushed.returncode:
            said = [line for line in pushed.stderr.splitlines() if line.strip()]
            if any("non-fast-forward" in line or "fetch first" in line or "rejected" in line for line in said):
                raise ChannelError(
                    f"{self.url} {BRANCH} moved while publishing (another publish?); "
                    "nothing was changed there: rerun the command"
                )
            raise ChannelError(
                f"cannot push to the releases remote {self.url} ({BRANCH}): {why(pushed)}; check "
                "that you may write there."
            )
        return head


class DirChannel:
    """A directory served over static HTTPS (or copied anywhere): written in place."""

    def __init__(self, path):
        self.path = Path(path)
        self.url = str(self.path)

    def open(self) -> Path:
        self.path.mkdir(parents=True, exist_ok=True)
        return self.path

    def push(self, message: str) -> str:
        return ""
