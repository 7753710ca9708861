"""Waves decided on the robot: who is in which wave of a release, when a
wave opens, how many failures it tolerates, and maintenance windows.  Pure:
every function takes what it needs (names, versions, times) and no host.

- A release's robots are ranked by sha256(name + str(version)): the order
  changes with every release, so the same robot is not always the canary.
- Wave 0 is the first ``canary`` robots (a count, or a share of the list
  rounded up); the plan's ``waves`` are cumulative shares of the whole list
  (rounded up), the last one 100%.  A wave that would be empty is dropped.
- Wave k opens at ``published + k * pause`` seconds, if the release is not
  halted and the earlier waves' robots have reported at most ``max_failed``
  failures for this version (a share is of the whole list, rounded down).
- A maintenance window is ``DAYS HH:MM-HH:MM [UTC]``: DAYS is ``daily``, a
  day (``Mon``), a range (``Mon-Fri``, ``Fri-Mon``) or a list (``Sat,Sun``);
  an end before the start runs past midnight into the next day; times are
  the robot's local time unless ``UTC`` follows.
"""

from __future__ import annotations

import datetime
import hashlib
import math
import re
from dataclasses import dataclass

_COUNT = re.compile(r"(0|[1-9][0-9]{0,5})(%?)")


@dataclass(frozen=True)
class Count:
    """A number of robots, absolute ("2") or a share of the fleet ("25%")."""

    value: int
    percent: bool

    def of(self, total: int, round_up: bool) -> int:
        if not self.percent:
            return self.value
        exact = total * self.value / 100
        return math.ceil(exact) if round_up else math.floor(exact + 1e-9)

    def __str__(self) -> str:
        return f"{self.value}{'%' if self.percent else ''}"


def parse_count(text, option: str) -> Count:
    """'3' or '25%' -> Count; anything else raises ValueError naming the option."""
    if isinstance(text, bool):
        raise ValueError(f"{option}: expected a number of robots or a percentage like 25%, got {text!r}")
    match = _COUNT.fullmatch(str(text).strip())
    if not match or (match.group(2) and int(match.group(1)) > 100):
        raise ValueError(f"{option}: expected a number of robots or a percentage like 25%, got {text!r}")
    return Count(int(match.group(1)), bool(match.group(2)))


def allowed_failures(max_failed: Count, total: int) -> int:
    """Failures a rollout tolerates; one more stops it (Ansible's
    max_fail_percentage: a share is rounded down)."""
    return max_failed.of(total, round_up=False)


@dataclass(frozen=True)
class Plan:
    """A release's rollout plan (the record's "rollout")."""

    canary: Count = Count(1, False)
    waves: tuple[Count, ...] = (Count(100, True),)
    pause: int = 600
    max_failed: Count = Count(0, False)

    def to_dict(self) -> dict:
        return {
            "canary": str(self.canary),
            "waves": [str(w) for w in self.waves],
            "pause": self.pause,
            "max_failed": str(self.max_failed),
        }


MAX_PAUSE = 366 * 86400


def parse_plan(raw, where: str = "rollout") -> Plan:
    """The record's "rollout" mapping -> Plan; ValueError with one line naming the field."""
    if not isinstance(raw, dict):
        raise ValueError(f"{where}: expected a mapping (canary, waves, pause, max_failed), got {type(raw).__name__}")
    unknown = sorted(set(raw) - {"canary", "waves", "pause", "max_failed"})
    if unknown:
        raise ValueError(f"{where}: unknown field {unknown[0]!r} (fields: canary, waves, pause, max_failed)")
    default = Plan()
    canary = parse_count(raw.get("canary", str(default.canary)), f"{where}.canary")
    waves_raw = raw.get("waves", [str(w) for w in default.waves])
    if not isinstance(waves_raw, list) or not waves_raw:
        raise ValueError(f"{where}.waves: expected a list of cumulative shares ending at 100%, got {waves_raw!r}")
    waves = tuple(parse_count(w, f"{where}.waves[{i}]") for i, w in enumerate(waves_raw))
    for i, wave in enumerate(waves):
        if not wave.percent:
            raise ValueError(f"{where}.waves[{i}]: expected a share of the robots like 50%, got {str(wave)!r}")
        if i and wave.value <= waves[i - 1].value:
            raise ValueError(
                f"{where}.waves[{i}]: shares are cumulative and must rise, got {wave} after {waves[i - 1]}"
            )
    if waves[-1].value != 100:
        raise ValueError(f"{where}.waves: the last wave must be 100% (every robot), got {waves[-1]}")
    pause = raw.get("pause", default.pause)
    if isinstance(pause, bool) or not isinstance(pause, int) or not 0 <= pause <= MAX_PAUSE:
        raise ValueError(f"{where}.pause: expected seconds between waves (0 to {MAX_PAUSE}), got {pause!r}")
    max_failed = parse_count(raw.get("max_failed", str(default.max_failed)), f"{where}.max_failed")
    return Plan(canary, waves, pause, max_failed)


def rank(robots: list[str], version: int) -> list[str]:
    """The release's robots in wave order: by sha256(name + version)."""
    return sorted(robots, key=lambda name: (hashlib.sha256(f"{name}{version}".encode()).hexdigest(), name))


def waves(robots: list[str], version: int, plan: Plan) -> list[list[str]]:
    """The robots of each wave, wave 0 (the canaries) first; no empty wave."""
    ranked = rank(list(dict.fromkeys(robots)), version)
    total = len(ranked)
    bounds = [min(total, plan.canary.of(total, round_up=True))]
    bounds += [max(bounds[0], w.of(total, round_up=True)) for w in plan.waves]
    result, start = [], 0
    for end in bounds:
        if end > start:
            result.append(ranked[start:end])
            start = end
    return result


def wave_of(robot: str, robots: list[str], version: int, plan: Plan) -> int | None:
    """The index of ``robot``'s wave, None if the release is not for it."""
    for index, members in enumerate(waves(robots, version, plan)):
        if robot in members:
            return index
    return None


def opens_at(wave: int, published: datetime.datetime, plan: Plan) -> datetime.datetime:
    """When wave ``wave`` may start: ``published + wave * pause``."""
    return published + datetime.timedelta(seconds=wave * plan.pause)


def earlier_robots(robot: str, robots: list[str], version: int, plan: Plan) -> list[str]:
    """The robots of the waves before ``robot``'s (whose reports gate it)."""
    index = wave_of(robot, robots, version, plan)
    return [name for members in waves(robots, version, plan)[: index or 0] for name in members]


def describe(robots: list[str], version: int, plan: Plan, published: datetime.datetime, shown: int = 5) -> list[str]:
    """The signed plan in words, a line a wave: who opens when, under which
    budget (``publish`` prints it).  At most ``shown`` names a wave."""
    members = waves(robots, version, plan)
    allowed = allowed_failures(plan.max_failed, len(set(robots)))
    lines = [
        f"{len(members)} wave(s); wave k opens at publish + k x {plan.pause} s, and only while at most "
        f"{allowed} robot(s) of the earlier waves failed (--max-failed {plan.max_failed}):"
    ]
    for index, names in enumerate(members):
        canary = index == 0 and plan.canary.of(len(set(robots)), round_up=True) > 0
        listed = ", ".join(names[:shown]) + (f" and {len(names) - shown} more" if len(names) > shown else "")
        at = opens_at(index, published, plan).strftime("%Y-%m-%dT%H:%M:%SZ")
        lines.append(f"  wave {index}{' (canary)' if canary else ''}: {len(names)} robot(s) from {at}: {listed}")
    return lines


@dataclass(frozen=True)
class Gate:
    """Whether a robot may start now: ``open``, else ``why`` (one line) and,
    when only time stands in the way, ``at`` (when to look again)."""

    open: bool
    wave: int | None
    why: str | None = None
    at: datetime.datetime | None = None


def gate(
    robot: str,
    robots: list[str],
    version: int,
    plan: Plan,
    published: datetime.datetime,
    now: datetime.datetime,
    failed: int,
    halted: bool = False,
) -> Gate:
    """May ``robot`` start release ``version`` at ``now``?  ``failed``: how
    many robots of the earlier waves reported a failure for this version."""
    index = wave_of(robot, robots, version, plan)
    if index is None:
        return Gate(False, None, f"release {version} is not for {robot}")
    if halted:
        return Gate(False, index, f"release {version} is halted")
    allowed = allowed_failures(plan.max_failed, len(set(robots)))
    if index and failed > allowed:
        return Gate(
            False,
            index,
            f"wave {index} stopped by the failure budget: {failed} robot(s) of the earlier "
            f"waves failed (budget {allowed})",
        )
    at = opens_at(index, published, plan)
    if now < at:
        return Gate(False, index, f"waiting for wave {index} (opens at {at.strftime('%Y-%m-%dT%H:%M:%SZ')})", at)
    return Gate(True, index)


# Maintenance windows ------------------------------------------------------

DAYS = ("mon", "tue", "wed", "thu", "fri", "sat", "sun")
_WINDOW = re.compile(r"(\S+)\s+(\d{1,2}):(\d{2})-(\d{1,2}):(\d{2})(?:\s+(utc|local))?", re.IGNORECASE)


@dataclass(frozen=True)
class Window:
    """Days (0 = Monday) on which the window starts, its start and length in
    minutes, and whether its times are UTC (else the robot's local time)."""

    days: frozenset[int]
    start: int
    minutes: int
    utc: bool
    text: str


_LONG = ("monday", "tuesday", "wednesday", "thursday", "friday", "saturday", "sunday")


def _day(name: str) -> int:
    """0 (Monday) to 6 for 'Mon' or 'monday' (any case), -1 otherwise."""
    name = name.lower()
    for index, (short, long) in enumerate(zip(DAYS, _LONG)):
        if name in (short, long):
            return index
    return -1


def _days(spec: str, text: str) -> frozenset[int]:
    if spec.lower() in ("daily", "*"):
        return frozenset(range(7))
    found: set[int] = set()
    for part in spec.split(","):
        first, dash, last = part.partition("-")
        a, b = _day(first), _day(last if dash else first)
        if a < 0 or b < 0:
            raise ValueError(
                f"maintenance window {text!r}: {part!r} is not a day or a range of days "
                "(Mon, Mon-Fri, Sat,Sun or daily)"
            )
        day = a
        found.add(day)
        while day != b:
            day = (day + 1) % 7
            found.add(day)
    return frozenset(found)


def parse_window(text) -> Window:
    """``Mon-Fri 01:00-05:00`` (local) or ``daily 22:00-02:00 UTC`` -> Window;
    ValueError with one line otherwise."""
    if not isinstance(text, str):
        raise ValueError(f"maintenance window: expected text like 'Mon-Fri 01:00-05:00', got {text!r}")
    match = _WINDOW.fullmatch(text.strip())
    if not match:
        raise ValueError(f"maintenance window {text!r}: expected DAYS HH:MM-HH:MM [UTC], e.g. 'Mon-Fri 01:00-05:00'")
    spec, h1, m1, h2, m2, zone = match.groups()
    for hour, minute in ((h1, m1), (h2, m2)):
        if int(hour) > 23 or int(minute) > 59:
            raise ValueError(f"maintenance window {text!r}: {hour}:{minute} is not a time of day (00:00 to 23:59)")
    start, end = int(h1) * 60 + int(m1), int(h2) * 60 + int(m2)
    if start == end:
        raise ValueError(
            f"maintenance window {text!r}: starts and ends at the same time; for all day write 00:00-23:59"
        )
    return Window(_days(spec, text), start, (end - start) % 1440, bool(zone and zone.lower() == "utc"), text.strip())


def in_window(windows: list[Window], when: datetime.datetime, local: datetime.tzinfo | None = None) -> bool:
    """Whether ``when`` (an aware time) falls in one of ``windows``; no
    windows: always.  ``local``: the robot's time zone (None: this process's)."""
    return not windows or any(_inside(w, when, local) for w in windows)


def _inside(window: Window, when: datetime.datetime, local) -> bool:
    moment = when.astimezone(datetime.timezone.utc if window.utc else local)
    minute = moment.hour * 60 + moment.minute
    for back in (0, 1):  # a window that started today, or yesterday and runs past midnight
        day = (moment.weekday() - back) % 7
        offset = minute + back * 1440 - window.start
        if day in window.days and 0 <= offset < window.minutes:
            return True
    return False


def next_window(
    windows: list[Window], when: datetime.datetime, local: datetime.tzinfo | None = None
) -> datetime.datetime | None:
    """The first minute at or after ``when`` inside a window (None: no windows)."""
    if not windows:
        return None
    moment = when.replace(second=0, microsecond=0)
    if moment < when:
        moment += datetime.timedelta(minutes=1)
    for _ in range(8 * 1440):
        if in_window(windows, moment, local):
            return moment
        moment += datetime.timedelta(minutes=1)
    return None
