"""``robotfleet status --html FILE``: the fleet on one page.

One self-contained HTML file made from the rows ``status --json`` prints:
a summary of the hosts' health, every host's row (health and why, what its
roles read: the table's columns), each host's history as its roles tell it
(StatusPart.history: the payload's releases), the latest push rollout's
waves and their progress (.rollout/, robotfleet/commands/rollout_plan.py),
the pull robots' waves for the newest release they have seen (their
reports), their last reports and their age, and when it was taken.  Nothing on it
is fetched (inline CSS, no script; its Content-Security-Policy forbids any
fetch), so it opens from a file, a mail or a CI artifact; it reflows to a
card per host on a phone.  Every value is escaped (jinja2's autoescape):
what a robot reports is text on the page, never markup.
"""

from __future__ import annotations

import datetime
from pathlib import Path

import jinja2

from robotfleet import atomicfile
from robotfleet.commands import rollout_plan
from robotfleet.commands.pull import rollout as pullrollout
from robotfleet.status_parts import columns, reporting, state_of

# Each host's health on the page, in the summary's order.
HEALTH = ("healthy", "drifted", "failed", "unreachable")
TEMPLATE = Path(__file__).with_name("statuspage.html.j2")
# Columns the page shows in their own places (the host and its health), not among the roles' cells.
OWN = ("host", "reachable", "rollout")


def age(seconds: float) -> str:
    """``42 s``, ``5 min``, ``3 h 10 min``, ``2 d 4 h`` (pure)."""
    seconds = max(0, int(seconds))
    if seconds < 60:
        return f"{seconds} s"
    minutes = seconds // 60
    if minutes < 60:
        return f"{minutes} min"
    hours, minutes = divmod(minutes, 60)
    if hours < 48:
        return f"{hours} h {minutes} min" if minutes else f"{hours} h"
    days, hours = divmod(hours, 24)
    return f"{days} d {hours} h" if hours else f"{days} d"


def _utc(text: str) -> datetime.datetime | None:
    try:
        return datetime.datetime.fromisoformat(str(text).replace("Z", "+00:00"))
    except ValueError:
        return None


def _cell(value) -> str:
    if value is True:
        return "yes"
    if value is False:
        return "no"
    return "-" if value in (None, "") else str(value)


def pull_view(row: dict, taken: datetime.datetime) -> dict | None:
    """A pull robot's last report as the page shows it (None: not a pull robot)."""
    if row.get("via") != "report":
        return None
    report = row.get("report") or {}
    when = _utc(report.get("time", "")) if report else None
    applied, seen = report.get("applied") or {}, report.get("seen") or {}
    return {
        "result": row.get("pull") or "no report",
        "reported": report.get("time"),
        "age": age((taken - when).total_seconds()) if when else None,
        "stale": bool(row.get("stale")),
        "applied": f"release {applied['version']}" + (f" at {applied['time']}" if applied.get("time") else "")
        if applied.get("version") is not None
        else None,
        "seen": f"release {seen['version']}" if seen.get("version") is not None else None,
        "reason": report.get("reason"),
    }


def host_view(row: dict, roles, shown: list[tuple[str, str]], taken: datetime.datetime) -> dict:
    state = state_of(row)
    history = [entry for role in reporting(roles) if role.status.history for entry in role.status.history(row)]
    pull = pull_view(row, taken)
    if pull and pull["applied"]:
        history.append(("applied (pull)", pull["applied"]))
    return {
        "host": row["host"],
        "kind": row.get("kind") or "-",
        "via": "pull report" if pull else "ssh",
        "health": state,
        "reason": row.get("error") or row.get("drift") or "",
        "cells": [(title, _cell(row.get(key))) for key, title in shown if key not in OWN],
        "history": history,
        "rollout": row.get("rollout"),
        "pull": pull,
    }


def wave_view(number, label: str, outcomes: list[tuple[str, str, str | None]]) -> dict:
    """A wave: its robots (name, where it stands, why), how far it got (done of its robots)."""
    done = sum(1 for _, o, _ in outcomes if o == "done")
    return {
        "number": number,
        "label": label,
        "hosts": outcomes,
        "done": done,
        "total": len(outcomes),
        "percent": round(100 * done / len(outcomes)) if outcomes else 100,
    }


def rollout_view(state: dict | None) -> dict | None:
    """The latest push rollout's waves, as its state (.rollout/) holds them."""
    if not state:
        return None
    waves = [
        wave_view(
            number,
            f"Wave {number}",
            [(h, rollout_plan.outcome(state, h), rollout_plan.reason(state, h)) for h in hosts],
        )
        for number, hosts in enumerate(state["waves"], 1)
    ]
    return {
        "key": state.get("key"),
        "status": state.get("status"),
        "summary": rollout_plan.summary(state),
        "waves": waves,
        "current": min(state.get("wave", 0) + 1, len(waves)),
    }


def pull_rollout_view(rows: list[dict]) -> dict | None:
    """The newest release the pull robots have seen, wave by wave as each
    robot placed itself (its report's wave; 0 the canary), and where each
    stands for it as ``robotfleet rollout`` follows it: done, failed, or
    pending (not yet, or not seen).  None: no pull robot has seen a release."""
    pulled = [r for r in rows if r.get("via") == "report"]
    seen = [((r.get("report") or {}).get("seen") or {}).get("version") for r in pulled]
    version = max((v for v in seen if isinstance(v, int)), default=None)
    if version is None:
        return None
    placed: dict = {}
    for r, saw in zip(pulled, seen):
        report = r.get("report") or {}
        outcome = pullrollout.outcome(report, version) or "pending"
        why = report.get("reason") if outcome == "failed" else None
        placed.setdefault(report.get("wave") if saw == version else None, []).append((r["host"], outcome, why))
    numbers = sorted(n for n in placed if n is not None)
    waves = [wave_view(n, "Wave 0 (canary)" if n == 0 else f"Wave {n}", placed[n]) for n in numbers]
    if None in placed:
        waves.append(wave_view("none", "Not placed yet (the release not seen)", placed[None]))
    return {"version": version, "waves": waves}


def render(rows: list[dict], rollout: dict | None, roles, taken: float) -> str:
    """The page (pure): ``rows`` as status --json prints them, the latest
    rollout's state, the roles that made the rows, when status ran (Unix time)."""
    moment = datetime.datetime.fromtimestamp(taken, datetime.timezone.utc).replace(microsecond=0)
    shown = columns(roles)
    hosts = [host_view(r, roles, shown, moment) for r in rows]
    counts = {name: sum(1 for h in hosts if h["health"] == name) for name in HEALTH}
    environment = jinja2.Environment(autoescape=True, undefined=jinja2.StrictUndefined, keep_trailing_newline=True)
    template = environment.from_string(TEMPLATE.read_text())
    return template.render(
        taken=moment.isoformat().replace("+00:00", "Z"),
        hosts=hosts,
        counts=counts,
        total=len(hosts),
        rollout=rollout_view(rollout),
        pull_rollout=pull_rollout_view(rows),
        pulls=[h for h in hosts if h["pull"]],
    )


def write(path: str, rows: list[dict], rollout: dict | None, roles, taken: float) -> None:
    """Replace ``path`` with the page atomically (a browser or a web server never reads half of it)."""
    atomicfile.write(path, render(rows, rollout, roles, taken), mode=0o644)
