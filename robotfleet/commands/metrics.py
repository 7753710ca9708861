"""``robotfleet status --metrics FILE`` and ``--format openmetrics``: the
fleet's state as OpenMetrics text (gauges only, no timestamps, ``# EOF``),
which Prometheus' text parsers read too: for node_exporter's textfile
collector (the file is replaced atomically: written beside it, then renamed)
or a Pushgateway (``... --format openmetrics | curl --data-binary @- URL``).

Per host (labels ``host``, ``kind``: robots or laptops, ``via``):

- ``robotfleet_up``: 1 it answered its status command, 0 it could not be reached;
- ``robotfleet_drift``: 1 it is not in its declared state where status can
  tell (each role's rollout part: the payload's images, running healthy), 0
  it is; absent when unreachable;
- each role's own, from its status part's ``metrics(row)`` (the payload's
  release, health and last change).

A pull robot's row (``via="report"``) comes from its last report
(robotfleet/commands/pull/status.py): ``up`` is 1 while the report is fresh,
its roles' gauges are its report's cells (none once stale: a stale report
does not vouch for the robot now), and it adds ``pull_report_stale``,
``pull_report_timestamp_seconds``, ``pull_seen_version``,
``pull_applied_version``, ``pull_result_info`` (labels ``result``,
``refusal``) and ``pull_failed``.

And ``robotfleet_status_timestamp_seconds``: when status ran (for alerts on
a stale file).

Other sources of rows (robots reporting elsewhere) join through ``REPORTERS``:
each is called with the inventory path and the host names status reached,
and returns rows shaped like status's own (``host``, ``reachable``, the
roles' cells, ``drift``), with ``via`` saying where the row came from
(status's own rows are ``via="ssh"``).
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable

from robotfleet import atomicfile
from robotfleet.checkers import one_line
from robotfleet.role import Metric

PREFIX = "robotfleet_"
# Rows of robots that report by themselves: fn(inventory_path, host_names) -> rows.
REPORTERS: list[Callable[[str, list[str]], list[dict]]] = []
_NAME = re.compile(r"[a-zA-Z_][a-zA-Z0-9_]*")


def engine_metrics(row: dict) -> list[Metric]:
    found = [
        Metric(
            "up",
            "1 the host answered its status command (a pull robot: its report is fresh), 0 it could "
            "not be reached (its report is stale or missing).",
            1 if row.get("reachable") else 0,
        )
    ]
    if row.get("reachable") and "drift" in row:
        found.append(
            Metric(
                "drift",
                "1 the host is not in its declared state (where status can tell), 0 it is.",
                1 if row["drift"] else 0,
            )
        )
    return found


def samples(rows: list[dict], roles) -> list[tuple[Metric, dict]]:
    """Every host's metrics with its labels."""
    found = []
    for row in rows:
        labels = {"host": row["host"], "kind": row.get("kind") or "", "via": row.get("via") or "ssh"}
        metrics = engine_metrics(row)
        if "pull" in row:
            from robotfleet.commands.pull import status as pullstatus

            metrics += pullstatus.metrics(row)
        if row.get("reachable"):
            for role in roles:
                if role.status and role.status.metrics:
                    metrics += role.status.metrics(row)
        found += [(metric, {**labels, **dict(metric.labels)}) for metric in metrics]
    return found


def render(rows: list[dict], roles, now: float) -> str:
    """The OpenMetrics text of ``rows`` (status's, then the reporters')."""
    families: dict[str, list[tuple[Metric, dict]]] = {}
    for metric, labels in samples(rows, roles):
        if not _NAME.fullmatch(metric.name):
            raise ValueError(f"metric name {metric.name!r} is not a valid OpenMetrics name")
        families.setdefault(metric.name, []).append((metric, labels))
    families["status_timestamp_seconds"] = [
        (Metric("status_timestamp_seconds", "When robotfleet status read the fleet (Unix time).", now), {})
    ]
    lines = []
    for name, members in families.items():
        lines += [f"# HELP {PREFIX}{name} {_help(members[0][0].help)}", f"# TYPE {PREFIX}{name} gauge"]
        for metric, labels in members:
            shown = ",".join(f'{key}="{_label(value)}"' for key, value in labels.items())
            lines.append(
                f"{PREFIX}{name}{{{shown}}} {_number(metric.value)}"
                if shown
                else f"{PREFIX}{name} {_number(metric.value)}"
            )
    return "\n".join(lines + ["# EOF"]) + "\n"


def _label(value) -> str:
    """A label value: any control character (robots supply release ids)
    shown as text (\\x1b), then OpenMetrics' escapes."""
    return one_line(str(value)).replace("\\", "\\\\").replace('"', '\\"')


def _help(text: str) -> str:
    return one_line(text).replace("\\", "\\\\")


def _number(value: float) -> str:
    if isinstance(value, bool):
        return "1" if value else "0"
    if isinstance(value, int) or (isinstance(value, float) and value.is_integer() and abs(value) < 2**53):
        return str(int(value))
    if math.isnan(value):
        return "NaN"
    if math.isinf(value):
        return "+Inf" if value > 0 else "-Inf"
    return repr(float(value))


def write(path: str, text: str) -> None:
    """Replace ``path`` with ``text`` atomically (a collector never reads
    half a file), mode 0644."""
    atomicfile.write(path, text, mode=0o644)


def reported(inventory: str, reached: list[str]) -> list[dict]:
    """The rows of robots that report by themselves (REPORTERS)."""
    return [row for reporter in REPORTERS for row in reporter(inventory, reached)]
