"""A wake's one line in the journal, and the CPU it counts: the full
wake's (robotfleet/pull/robot/wake_report.py) and the idle check's
(robotfleet/pull/robot/idle.py), which imports nothing more than this."""

from __future__ import annotations

import resource


def cpu_seconds() -> float:
    """CPU time of this process and everything it ran (and waited for)."""
    usage = [resource.getrusage(who) for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)]
    return round(sum(u.ru_utime + u.ru_stime for u in usage), 3)


def journal_line(report: dict, sent: str, seconds: float) -> str:
    """The wake's one line: its outcome, and what it cost (the whole wake:
    CPU of the agent and everything it ran, bytes over the network)."""
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
        f"requests; {sent}"
    )
