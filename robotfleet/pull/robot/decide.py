"""What a pull robot does with a verified release record (pure): apply it,
wait (its wave, its maintenance window), stop (a halt, its wave stopped
by the failure budget, a release it already failed), or nothing (already applied).

The agent (robotfleet/pull/robot/agent.py) asks twice when its wave is not the
first: once on time and windows alone, and, only when those are open, again
with the failures the earlier waves reported (fetched just then, so an idle
or waiting robot never reads other robots' reports).
"""

from __future__ import annotations

import datetime
from dataclasses import dataclass

from robotfleet.pull.protocol import waves

# A release whose run failed for another reason than its health gate (the
# network, a full disk) is tried again, this many times in all; one that
# was rolled back is not (it would fail the same way, and restart the
# payload each time).
MAX_TRIES = 3
APPLY = "apply"
STOPPED = "stopped"  # its wave stopped by the failure budget (a halt is the operator's signed record)


@dataclass(frozen=True)
class Decision:
    """``result``: APPLY, or the report's result (up-to-date, waiting,
    halted, stopped, rolled-back, failed); ``reason``: one line; ``wave``: the
    robot's wave of this release; ``earlier``: robots whose reports decide
    (asked for when only they stand in the way)."""

    result: str
    reason: str | None = None
    wave: int | None = None
    earlier: tuple[str, ...] = ()


def decide(
    record,
    robot: str,
    applied: int,
    attempted: dict | None,
    now: datetime.datetime,
    windows=(),
    local=None,
    failed: int | None = None,
) -> Decision:
    """``applied``: the version this robot applied last (0: none);
    ``attempted``: {version, result, tries, reason} of its last try;
    ``windows``: its maintenance windows (waves.Window); ``failed``: the
    earlier waves' failures for this version, None while not yet read."""
    version = record.version
    if version <= applied:
        return Decision("up-to-date", None)
    if record.halt:
        return Decision("halted", f"release {version} is a halt: {record.halt_reason or 'no reason given'}")
    if robot not in record.robots:
        return Decision("up-to-date", f"release {version} is not for {robot}")
    tried = attempted if attempted and attempted.get("version") == version else None
    if tried and (tried.get("result") == "rolled-back" or tried.get("tries", 0) >= MAX_TRIES):
        return Decision(
            tried["result"],
            f"release {version} failed here ({tried.get('reason') or 'no reason'}); waiting for a newer release",
        )
    plan = record.rollout
    gate = waves.gate(robot, list(record.robots), version, plan, record.published_at, now, failed or 0)
    if not gate.open and gate.at is not None:
        return Decision("waiting", gate.why, gate.wave)
    if not gate.open:  # the earlier waves failed more than the budget: not a halt, which only a signed record is
        return Decision(STOPPED, gate.why, gate.wave)
    if windows and not waves.in_window(list(windows), now, local):
        opens = waves.next_window(list(windows), now, local)
        when = f"; next at {opens.astimezone(datetime.timezone.utc):%Y-%m-%dT%H:%M:%SZ}" if opens else ""
        return Decision("waiting", f"outside the maintenance window{when}", gate.wave)
    earlier = waves.earlier_robots(robot, list(record.robots), version, plan)
    if earlier and failed is None:
        return Decision("waiting", "reading the earlier waves' reports", gate.wave, tuple(earlier))
    return Decision(APPLY, None, gate.wave)
