"""Where reports live on the fleet remote and how both sides read them:
``refs/reports/<robot>`` (the robot's own ref, which only it may write), a
commit holding ``report.json``.  All of a fetch's reports are read with one
``git cat-file`` (the operator's status at 10,000 robots, a robot's look at
the earlier waves)."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

from robotfleet.pull.protocol.reports import ReportError, parse


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


def fetch_all(url: str, cache: Path, timeout: int = 300) -> None:
    """Fetch every robot's report into the bare repository ``cache`` (one
    fetch; refs of robots that no longer report are pruned)."""
    if not (cache / "HEAD").exists():
        cache.mkdir(parents=True, exist_ok=True)
        _git(cache, "init", "--bare", "-q")
    _git(cache, "-c", "protocol.version=2", "fetch", "--quiet", "--no-tags", "--prune", url,
         "+refs/reports/*:refs/reports/*", timeout=timeout)


def read_all(cache: Path) -> dict[str, dict]:
    """robot -> its parsed report, or {"error": line} when it cannot be read."""
    def git(what, *args, stdin=None):
        return _git(cache, *args, stdin=stdin)

    found = {}
    for robot, data in read_reports(git, "refs/reports/").items():
        try:
            found[robot] = parse(data, robot)
        except ReportError as error:
            found[robot] = {"robot": robot, "error": str(error)}
    return found


def _git(where: Path, *args: str, stdin: bytes | None = None, timeout: int = 300) -> bytes:
    try:
        done = subprocess.run(["git", "-C", str(where), *args], input=stdin, capture_output=True, timeout=timeout,
                              env=dict(os.environ, GIT_TERMINAL_PROMPT="0"))
    except subprocess.TimeoutExpired:
        raise ReportError(f"git {args[0]}: no answer within {timeout} s") from None
    except OSError as error:
        raise ReportError(f"git: {error}") from None
    if done.returncode:
        lines = [line for line in done.stderr.decode(errors="replace").splitlines() if line.strip()]
        raise ReportError(f"git {' '.join(a for a in args[:3] if not a.startswith('-'))}: "
                          f"{lines[-1].strip() if lines else f'exit {done.returncode}'}")
    return done.stdout
