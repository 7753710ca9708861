"""A wake's one line in the journal, and the CPU it counts."""

from __future__ import annotations

import resource
import time
from contextlib import contextmanager


def cpu_seconds() -> float:
    """CPU time of this process and everything it ran (and waited for)."""
    usage = [resource.getrusage(who) for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)]
    return round(sum(u.ru_utime + u.ru_stime for u in usage), 3)


class Phases:
    """Where a full wake's seconds went, in the order its steps ran: the
    journal line ends with them, so a slow wake says which step was slow."""

    def __init__(self):
        self.seconds: dict[str, float] = {}

    @contextmanager
    def timed(self, name: str):
        started = time.monotonic()
        try:
            yield
        finally:
            self.add(name, time.monotonic() - started)

    def add(self, name: str, seconds) -> None:
        if _figure(seconds):
            self.seconds[name] = self.seconds.get(name, 0.0) + seconds

    def add_run(self, seconds: float, took) -> None:
        """A converge run's seconds: its deploy and status read as it timed
        them (figures it can have spent), the rest (the release's Python and
        roles loading) as load."""
        said = took if isinstance(took, dict) else {}
        took = {k: v for k, v in said.items() if k in ("deploy", "status") and _figure(v) and v < seconds}
        self.add("load", seconds - sum(took.values()))
        for name, spent in took.items():
            self.add(name, spent)

    def text(self) -> str:
        return ", ".join(f"{name} {seconds:.2f} s" for name, seconds in self.seconds.items())


def journal_line(report: dict, sent: str, seconds: float, phases: Phases | None = None) -> str:
    """The wake's one line: its outcome, and what it cost (the whole wake:
    CPU of the agent and everything it ran, bytes over the network), then
    where its seconds went (``phases``, a full wake's)."""
    check = report.get("check") or {}
    seen = report.get("seen") or {}
    head = f"robot-pull: {report['result']}"
    if seen:
        head += f" (release {seen.get('version')})"
    if report.get("reason"):
        head += f": {report['reason']}"
    return (
        f"{head}; {seconds:.1f} s, {check.get('cpu', 0):.2f} s CPU, "
        f"sent {check.get('sent', 0)} B, received {check.get('received', 0)} B in {check.get('requests', 0)} "
        f"requests; {sent}" + (f" [{phases.text()}]" if phases and phases.seconds else "")
    )


def _figure(seconds) -> bool:
    """A number of seconds a step can have taken (a JSON line's value may be anything)."""
    return isinstance(seconds, (int, float)) and not isinstance(seconds, bool) and seconds >= 0
