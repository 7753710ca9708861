"""Where reports live on the fleet remote and how both sides read them:
``refs/reports/<robot>`` (the robot's own ref, which only it may write), a
commit holding ``report.json``.  Every reader goes through ``read`` (status,
pull-enroll, rollout, a robot's look at the earlier waves): one ``git
cat-file`` for all of a fetch's reports, each checked by its size before it
is read, and nothing a robot pushed more than its own row.

With the reports sharded (``report_shards``), ``fetch_every`` fetches the
fleet remote's own report refs (the single-repository layout, kept while
robots move) and its read copy of the shards' reports (``COPY``, kept by the
git server's hook, files/git-server/post-receive: one commit, each report at
``<shard>/<robot>``), read with ``read_copy``: a robot's report only from its
own shard's path.  A fleet remote without that copy has every shard fetched
concurrently, each into its own cache, read each with ``read``.  A robot's
report is taken only from its own shard or the fleet remote, the newer of the
two when both have one."""

from __future__ import annotations

import functools
import os
import re
import subprocess
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from robotfleet import keepalive
from robotfleet.checkers import one_line
from robotfleet.pull.protocol import catfile, report_shards
from robotfleet.pull.protocol.reports import MAX_BYTES, ReportError, parse


def fetch_all(url: str, cache: Path, timeout: int = 300) -> None:
    """Fetch every robot's report into the bare repository ``cache`` (one
    fetch; refs of robots that no longer report are pruned)."""
    if not (cache / "HEAD").exists():
        cache.mkdir(parents=True, exist_ok=True)
        _git(cache, "init", "--bare", "-q")
    _git(
        cache,
        "-c",
        "protocol.version=2",
        "fetch",
        "--quiet",
        "--no-tags",
        "--prune",
        *filter_args(url),
        url,
        "+refs/reports/*:refs/reports/*",
        COPY_SPEC,
        timeout=timeout,
    )
    unpromise(cache, url)


def filter_args(url: str) -> list[str]:
    """A fetch's blob size filter: where the server allows it
    (``uploadpack.allowFilter``), no blob over the cap is downloaded (its
    report reads as missing); elsewhere git warns and fetches it all, and
    the cap applies as it is read.  Over SSH and local repositories only,
    with a git known to take a filter into a repository that is no partial
    clone (2.39): over a static HTTPS mirror (git's "dumb" protocol) a
    filtered fetch asks again for each object it left out, without end."""
    if not url.startswith(("ssh://", "file://", "/")) and not _SCP_LIKE.match(url):
        return []
    return [f"--filter=blob:limit={MAX_BYTES + 1}"] if _git_version() >= (2, 39) else []


def unpromise(repo: Path, url: str) -> None:
    """Forget what a filtered fetch from ``url`` wrote (the remote as a
    promisor): reading a blob it left out must answer "missing", never
    fetch it after all."""
    if filter_args(url):
        subprocess.run(
            ["git", "-C", str(repo), "config", "--remove-section", f"remote.{url}"],
            capture_output=True,
            check=False,
        )


_SCP_LIKE = re.compile(r"[^/:]+@[^/:]+:")


@functools.cache
def _git_version() -> tuple[int, ...]:
    try:
        said = subprocess.run(["git", "version"], capture_output=True, text=True, check=False).stdout
    except OSError:
        return (0,)
    found = re.search(r"(\d+)\.(\d+)", said)
    return (int(found[1]), int(found[2])) if found else (0,)


FETCHERS = 8  # shards fetched at once
# The git server's read copy of every shard's reports (files/git-server/post-receive);
# the glob fetches it when it is there (and prunes it when it is gone).
COPY = "refs/report-copy"
COPY_SPEC = f"+{COPY}*:{COPY}*"


def fetch_every(url: str, count: int, cache: Path, timeout: int = 300) -> dict[str, dict]:
    """Every robot's report from the fleet remote ``url`` and its ``count``
    report shards (fetched concurrently into ``cache`` and ``cache``-shards/<i>),
    read each from its robot's own shard (or the fleet remote's)."""
    fetch_all(url, cache, timeout)
    fleet = read_all(cache)
    if count and has(cache, COPY):
        return merged([fleet, read_copy(cache, COPY, count)])
    places = [(shard, cache.parent / f"{cache.name}-shards" / str(shard)) for shard in range(count)]

    def one(place) -> dict[str, dict]:
        shard, where = place
        fetch_all(report_shards.shard_url(url, shard), where, timeout)
        found = read_all(where)
        return {robot: report for robot, report in found.items() if report_shards.shard_of(robot, count) == shard}

    if not places:
        return fleet
    with ThreadPoolExecutor(max_workers=min(FETCHERS, len(places))) as pool:
        return merged([fleet, *pool.map(one, places)])


def merged(sources: list[dict[str, dict]]) -> dict[str, dict]:
    """robot -> its report among ``sources`` (each robot -> report): a
    readable one before an unreadable one, then the newest (a robot that
    moved to its shard left its older report in the fleet remote)."""
    found: dict[str, dict] = {}
    for source in sources:
        for robot, report in source.items():
            if robot not in found or _rank(report) > _rank(found[robot]):
                found[robot] = report
    return found


def _rank(report: dict) -> tuple:
    return ("error" not in report, report.get("time") or "")


def read_all(cache: Path) -> dict[str, dict]:
    """robot -> its parsed report, or {"robot", "error": line} when it cannot be read."""
    return read(cache, "refs/reports/")


def read(repo: Path, prefix: str, wanted: set[str] | None = None, timeout: int = 300) -> dict[str, dict]:
    """robot -> the report of each ref ``<prefix><robot>`` of the local
    repository ``repo`` (a commit holding report.json), parsed, or {"robot",
    "error": line} when it cannot be read; ``wanted``: these robots only.
    Every reader of reports goes through here (status, pull-enroll, rollout,
    a robot's wave decision): nothing a robot pushed is more than its own
    row, and no report is read whole into memory before its size is known."""
    listed = _git(repo, "for-each-ref", "--format=%(refname) %(objectname)", prefix, timeout=timeout)
    refs = {}
    for line in filter(None, listed.decode(errors="replace").split("\n")):
        name, _, commit = line.partition(" ")
        robot = name[len(prefix) :]
        if wanted is None or robot in wanted:
            refs[robot] = commit
    try:
        found = catfile.blobs(repo, [f"{commit}:report.json" for commit in refs.values()], MAX_BYTES, timeout)
    except catfile.CatFileError as error:
        raise ReportError(str(error)) from None
    return {robot: _parsed(robot, data) for robot, data in zip(refs, found)}


def has(repo: Path, ref: str) -> bool:
    return bool(_git(repo, "for-each-ref", "--format=%(objectname)", ref).strip())


def read_copy(repo: Path, ref: str, count: int, wanted: set[str] | None = None, timeout: int = 300) -> dict[str, dict]:
    """robot -> its report in the read copy ``ref`` of the local repository
    ``repo`` (a commit holding ``<shard>/<robot>`` for each report; ``count``
    shards), read as ``read`` reads a ref: a robot's only from its own
    shard's path, each blob checked by its size before it is read."""
    listed = _git(repo, "ls-tree", "-r", "-z", "--full-tree", ref, timeout=timeout)
    blobs = {}
    for entry in filter(None, listed.split(b"\0")):
        info, _, path = entry.decode(errors="replace").partition("\t")
        shard, _, robot = path.partition("/")
        if (
            (wanted is None or robot in wanted)
            and shard.isascii()
            and shard.isdigit()
            and robot
            and "/" not in robot  # the hook writes <shard>/<robot>, nothing deeper
            and report_shards.shard_of(robot, count) == int(shard)
        ):
            blobs[robot] = info.split()[-1]
    try:
        found = catfile.blobs(repo, list(blobs.values()), MAX_BYTES, timeout)
    except catfile.CatFileError as error:
        raise ReportError(str(error)) from None
    return {robot: _parsed(robot, data) for robot, data in zip(blobs, found)}


def _parsed(robot: str, data: bytes | str) -> dict:
    try:
        if isinstance(data, str):
            raise ReportError(f"report of {robot}: report.json: {data}")
        return parse(data, robot)
    except ReportError as error:
        return {"robot": robot, "error": one_line(str(error))}


def _git(where: Path, *args: str, stdin: bytes | None = None, timeout: int = 300) -> bytes:
    env = dict(os.environ, GIT_TERMINAL_PROMPT="0")
    try:
        done = subprocess.run(
            ["git", "-C", str(where), *args],
            input=stdin,
            capture_output=True,
            timeout=timeout,
            # a fetch from the fleet remote: its ssh gives up on a frozen server (robotfleet/keepalive.py)
            env=keepalive.git_environment(env, str(where)) if "fetch" in args else env,
        )
    except subprocess.TimeoutExpired:
        raise ReportError(f"git {args[0]}: no answer within {timeout} s") from None
    except OSError as error:
        raise ReportError(f"git: {error}") from None
    if done.returncode:
        lines = [line for line in done.stderr.decode(errors="replace").splitlines() if line.strip()]
        raise ReportError(
            f"git {' '.join(a for a in args[:3] if not a.startswith('-'))}: "
            f"{lines[-1].strip() if lines else f'exit {done.returncode}'}"
        )
    return done.stdout
