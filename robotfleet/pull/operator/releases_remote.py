"""The fleet's releases remote, named once, which every pull command uses.

publish, halt and keys (the releases branch), status, rollout and
pull-enroll (the pull robots' reports) take it from, in this order:
--remote NAME|URL; the checkout's git config ``robotfleet.remote``
(``git config robotfleet.remote URL``: e.g. the git server's ssh URL where
the robots fetch from an https mirror); the fleet file's pull robots'
``pull_remote`` (for reports, ``pull_report_remote`` where set), when they
all name one.  Never the checkout's ``origin`` by default: that is the
deploy repository, which docs/guides/pull.md keeps apart from the releases (robots
can read all of a remote they fetch from), so a command that writes there is
refused unless ``--remote origin`` names it.
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

CONFIG = "robotfleet.remote"
DEPLOY = "origin"
HOW = (
    f"name it once: git config {CONFIG} URL in the checkout (or pull_remote for the pull robots in the fleet "
    "file), or give --remote URL"
)


class Unnamed(Exception):
    """No remote, or one that must not be written to by default (one line; the command exits 2)."""


def _git(checkout, *args: str) -> str | None:
    try:
        done = subprocess.run(
            ["git", "-C", str(checkout), *args],
            capture_output=True,
            text=True,
            timeout=30,
            check=False,
            env={**os.environ, "GIT_TERMINAL_PROMPT": "0"},
        )
    except (OSError, subprocess.TimeoutExpired):
        return None
    return done.stdout.strip() or None if done.returncode == 0 else None


def configured(checkout) -> str | None:
    """The checkout's ``git config robotfleet.remote``, if set."""
    return _git(checkout, "config", "--get", CONFIG)


def named_by(hosts, reports: bool = False) -> list[str]:
    """The distinct remotes the pull hosts [(name, data)] name, in fleet order (pure): their ``pull_remote``,
    or for reports their ``pull_report_remote`` where set."""
    from robotfleet.fleet import pull_mode

    found: list[str] = []
    for _, data in hosts:
        if not pull_mode.pulls(data):
            continue
        remote = pull_mode.value(data, "pull_remote")
        url = (pull_mode.value(data, "pull_report_remote") if reports else None) or remote
        if url and url not in found:
            found.append(url)
    return found


def choose(given: str | None, config: str | None, fleet: list[str], unread: str = "") -> str:
    """The remote to use (pure): --remote, else the git config, else the one remote the pull robots name.
    ``unread``: why the fleet file could not be read, if it could not."""
    if given:
        return given
    if config:
        return config
    if len(fleet) == 1:
        return fleet[0]
    if fleet:
        raise Unnamed(
            f"the pull robots name {len(fleet)} remotes ({', '.join(fleet[:3])}); "
            f"say which one the operator uses: {HOW}."
        )
    fleet_said = (
        f"the fleet file could not be read: {unread}" if unread else "no pull robot with pull_remote in the fleet file"
    )
    raise Unnamed(
        f"no releases remote is named (no --remote, no {CONFIG} in the checkout's git config, {fleet_said}); {HOW}."
    )


def _same(one: str, other: str) -> bool:
    def plain(url: str) -> str:
        url = url.rstrip("/").removesuffix(".git").removeprefix("file://")
        return os.path.realpath(url) if "://" not in url and not _scp_like(url) else url

    return plain(one) == plain(other)


def _scp_like(url: str) -> bool:
    head = url.split("/", 1)[0]
    return ":" in head and not Path(url).exists()


def refuse_deploy_remote(checkout, given: str | None, url: str) -> None:
    """Unnamed when ``url`` is the deploy repository's own remote (origin's URL) and --remote origin did not
    name it: a command that writes the releases branch would put it beside the deploy code."""
    if given == DEPLOY:
        return
    origin = _git(checkout, "remote", "get-url", DEPLOY)
    resolved = _git(checkout, "remote", "get-url", url) or url
    if origin and _same(resolved, origin):
        raise Unnamed(
            f"{url} is the deploy repository's own remote ({DEPLOY}), and robots can read all of a remote "
            f"they fetch from; keep the releases on another remote ({HOW}), or give --remote {DEPLOY} to "
            "publish there anyway."
        )


def fleet_hosts(checkout, fleet: str | None = None) -> tuple[list[tuple[str, dict]], str]:
    """The fleet file's hosts [(name, data)] as the checkout has it (``fleet``, else $ROBOT_FLEET, else
    inventories/robots.yaml), and why not when it cannot be read (its first problem)."""
    from robotfleet import deploy_roles
    from robotfleet.fleet.validate import FleetError, load

    path = Path(checkout, fleet or os.environ.get("ROBOT_FLEET") or "inventories/robots.yaml")
    try:
        read = load(path, deploy_roles.registry())
    except FleetError as error:
        return [], error.lines[0] if error.lines else str(path)
    except OSError as error:
        return [], f"{path}: {error.strerror}"
    return [host for group in ("robots", "laptops") for host in read.hosts(group)], ""


def of(
    checkout, given: str | None, hosts=None, fleet: str | None = None, writes: bool = False, reports: bool = False
) -> str:
    """The releases remote (a name of the checkout or a URL) for a command; Unnamed if none is named, or if a
    command that ``writes`` would write to the deploy repository's remote without --remote origin."""
    config = None if given else configured(checkout)
    unread = ""
    if not given and not config and hosts is None:
        hosts, unread = fleet_hosts(checkout, fleet)
    url = choose(given, config, named_by(hosts or [], reports), unread)
    if writes:
        refuse_deploy_remote(checkout, given, url)
    return url
