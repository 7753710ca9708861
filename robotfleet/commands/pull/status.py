"""The pull robots' rows of ``robotfleet status``: from the reports they push
to the fleet remote (refs/reports/<robot>), fetched in one go, or, with
``pull_report_shards``, from each robot's report shard, the shards fetched
concurrently (robotfleet/pull/protocol/report_shards.py); no SSH.

A row holds what the robot's own status read (the same columns as a push
robot's), and two more: PULL (the outcome of its last check and the
release) and REPORTED (when; "STALE" once older than pull_stale_after
heartbeats, each with an interval and its jitter).  A robot with no report or a stale one counts
as unreachable, so does one whose last check could not fetch from its releases remote (its words
kept in "error"); a refused, failed or rolled-back release as failed.  Rows
say ``via: "report"``; ``metrics(row)`` are their gauges for
``status --metrics`` beside the roles' (read from the report's cells).
"""

from __future__ import annotations

import datetime
from pathlib import Path

import robotfleet
from robotfleet.checkers import one_line
from robotfleet.fleet import pull_mode
from robotfleet.pull.operator import channel, releases_remote
from robotfleet.pull.protocol import report_shards, report_store, reports
from robotfleet.pull.protocol.record import parse_time
from robotfleet.role import Metric

COLUMNS = [("pull", "PULL"), ("reported", "REPORTED")]
FAILED = ("refused", "failed", "rolled-back")


class ReportsUnavailable(Exception):
    """The fleet remote's reports cannot be read (one line)."""


def remote_of(given: str | None, hosts=(), checkout: Path = robotfleet.CHECKOUT) -> str:
    """The remote to read the pull hosts' [(name, data)] reports from: --remote, else the fleet's releases
    remote as releases_remote.py names it (their pull_report_remote where set)."""
    try:
        return channel.remote_url(checkout, releases_remote.of(checkout, given, hosts=list(hosts), reports=True))
    except (channel.ChannelError, releases_remote.Unnamed) as error:
        raise ReportsUnavailable(f"no remote to read the pull robots' reports from: {error}") from None


def shards_of(hosts) -> int:
    """The fleet's report shard count: pull_report_shards, one value for all
    the pull hosts [(name, data)] (a robot reads the others' shards with its own)."""
    counts = {}
    for name, data in hosts:
        counts.setdefault(pull_mode.value(data, "pull_report_shards"), name)
    if len(counts) > 1:
        (one, first), (other, second) = sorted(counts.items())[:2]
        raise ReportsUnavailable(
            f"pull_report_shards: {first} has {one}, {second} has {other}: give every pull robot the same"
        )
    return next(iter(counts), report_shards.SINGLE)


def fetch(url: str, cache: Path | None = None, shards: int = report_shards.SINGLE) -> dict[str, dict]:
    """Every robot's report from ``url`` and its ``shards`` report shards
    (fetched into a local cache, the shards concurrently)."""
    cache = cache or robotfleet.CHECKOUT / ".robotfleet" / "reports"
    try:
        return report_store.fetch_every(url, shards, cache)
    except reports.ReportError as error:
        raise ReportsUnavailable(
            f"reports from {url}{f' and its {shards} shards' if shards else ''}: {error}"
        ) from None


def pull_cell(report: dict) -> str:
    seen = (report.get("seen") or {}).get("version")
    applied = (report.get("applied") or {}).get("version")
    text = report["result"]
    if report["result"] in ("applied", "up-to-date") and applied:
        text += f" {applied}"
    elif seen:
        text += f" {seen}"
    if report.get("refusal"):
        text += f" ({report['refusal']})"
    elif report["result"] == "stopped":
        text += " (failure budget)"
    return text


def row(name: str, report: dict | None, data, now: datetime.datetime, url: str) -> dict:
    """A status row for pull robot ``name`` (pure)."""
    if report is None:
        return {
            "host": name,
            "reachable": False,
            "via": "report",
            "pull": "no report",
            "reported": None,
            "stale": True,
            "error": f"no report in refs/reports/{name} of {url} (the agent has not reported yet, "
            "or cannot reach the remote)",
        }
    if "error" in report:
        return {
            "host": name,
            "reachable": False,
            "via": "report",
            "pull": "unreadable",
            "reported": None,
            "stale": True,
            "error": report["error"],
        }
    cells = {k: v for k, v in (report.get("status") or {}).items() if k not in ("host", "reachable", "error")}
    interval, jitter, stale_after, heartbeat = (
        pull_mode.value(data, f"pull_{name}") for name in ("interval", "jitter", "stale_after", "heartbeat")
    )
    limit = reports.stale_limit(interval, jitter, stale_after, heartbeat)
    is_stale = reports.stale(report, now, interval, jitter, stale_after, heartbeat)
    cells.update(
        host=name,
        reachable="pull",
        via="report",
        pull=pull_cell(report),
        report=report,
        reported=report["time"] + (" STALE" if is_stale else ""),
        stale=is_stale,
    )
    if is_stale:
        cells["reachable"] = False
        cells["error"] = f"stale report: last at {report['time']}, more than {stale_after} heartbeats ({limit} s) ago"
    elif stranded(report):  # the robot's own words, and it counts as out of reach, not failed
        cells.update(reachable=False, pull="remote out of reach")
        cells["error"] = one_line(f"out of reach of its releases remote: {report['reason']}")
    elif report["result"] in FAILED:
        cells["error"] = one_line(f"{report['result']}: {report.get('reason') or 'no reason given'}")
    return cells


# How the agent words a check that could not fetch from the releases remote (robotfleet/pull/robot/agent.py).
FETCH_FAILED = "fetch: "


def stranded(report: dict) -> bool:
    """Whether the robot's last check failed only because it could not reach its releases remote (a name it
    could not resolve, a link down): out of reach, as a push robot that does not answer, not a failed release."""
    return report["result"] == "failed" and (report.get("reason") or "").startswith(FETCH_FAILED)


def metrics(row: dict) -> list[Metric]:
    """A pull robot's own gauges, from its report (pure): whether the report
    is stale (or missing), when it was made, the versions seen and applied,
    and the outcome of the last check."""
    found = [
        Metric(
            "pull_report_stale",
            "1 the pull robot's report is stale, missing or unreadable, 0 it is fresh.",
            1 if row.get("stale", True) else 0,
        )
    ]
    report = row.get("report")
    if not report:
        return found
    found.append(
        Metric(
            "pull_report_timestamp_seconds",
            "When the pull robot made its last report (Unix time).",
            parse_time(report["time"], "time").timestamp(),
        )
    )
    for key in ("seen", "applied"):
        version = (report.get(key) or {}).get("version")
        if version is not None:
            found.append(
                Metric(f"pull_{key}_version", f"The newest release version the pull robot has {key}.", version)
            )
    found.append(
        Metric(
            "pull_result_info",
            "The outcome of the pull robot's last check, and why it refused.",
            1,
            (("result", report["result"]), ("refusal", report.get("refusal") or "")),
        )
    )
    found.append(
        Metric(
            "pull_failed",
            "1 the pull robot refused, failed or rolled back its release, 0 not.",
            1 if report["result"] in FAILED else 0,
        )
    )
    return found


def now() -> datetime.datetime:
    return datetime.datetime.now(datetime.timezone.utc)


def rows(hosts, url: str, found: dict[str, dict] | None = None) -> dict[str, dict]:
    """name -> row for the pull hosts [(name, data)]."""
    shards = shards_of(hosts)
    found = fetch(url, shards=shards) if found is None else found
    moment = now()
    return {
        name: row(name, found.get(name), data, moment, report_shards.report_url(url, name, shards))
        for name, data in hosts
    }
