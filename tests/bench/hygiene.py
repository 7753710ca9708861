"""Benchmark hygiene: a figure is taken on an idle machine or says it was not.

Every benchmark here calls ``wait`` before each sample it times.  Before a
figure's first sample it waits (up to ``patience`` seconds) for the 1-minute
load average to fall below ``LIMIT``.  Before its later samples the load
average still counts the figure's own previous sample (it decays over
minutes, and waiting for it would make a benchmark of 30 figures last hours),
so there it waits instead until nothing is running now: fewer than ``QUIET``
cores busy over ``QUIET_WINDOW`` seconds, read from /proc/stat, which counts
other work as well as ours.  Either way the 1-minute load goes next to the
sample.  ``Figure`` keeps the samples (at least ``MIN_SAMPLES``) with their
loads, and gives the median, the spread and whether every sample was taken
idle; a results file whose figures were not all idle says so, and
``python3 -m tests.bench`` refuses to overwrite RESULTS.md with them unless
told to (--write-loaded).
"""

from __future__ import annotations

import os
import statistics
import sys
import time
from dataclasses import dataclass, field

LIMIT = 1.5  # 1-minute load average on this 2-core machine
MIN_SAMPLES = 3
PATIENCE = float(os.environ.get("ROBOT_BENCH_PATIENCE", "600"))
QUIET = 0.5  # cores busy (of 2), averaged over QUIET_WINDOW
QUIET_WINDOW = 3.0


def load() -> float:
    return os.getloadavg()[0]


def wait_for_idle(label: str = "", limit: float = LIMIT, patience: float | None = None, poll: float = 5.0) -> float:
    """The 1-minute load average when the figure starts: the first reading
    below ``limit`` within ``patience`` seconds, else the last one."""
    deadline = time.monotonic() + (PATIENCE if patience is None else patience)
    current = load()
    told = False
    while current >= limit and time.monotonic() < deadline:
        if not told:
            print(
                f"[bench] {label}: load average {current:.2f} >= {limit}; waiting for an idle machine",
                file=sys.stderr,
                flush=True,
            )
            told = True
        time.sleep(poll)
        current = load()
    if current >= limit:
        print(
            f"[bench] {label}: still {current:.2f} after waiting; this figure is marked loaded",
            file=sys.stderr,
            flush=True,
        )
    return round(current, 2)


def busy_cores(window: float = QUIET_WINDOW) -> float:
    """How many cores were busy, on average, over the next ``window`` seconds."""

    def times() -> tuple[int, int]:
        with open("/proc/stat") as stat:
            fields = [int(x) for x in stat.readline().split()[1:]]
        idle = fields[3] + (fields[4] if len(fields) > 4 else 0)  # idle + iowait
        return sum(fields), idle

    total0, idle0 = times()
    time.sleep(window)
    total1, idle1 = times()
    spent = total1 - total0
    return 0.0 if spent <= 0 else round((os.cpu_count() or 1) * (1 - (idle1 - idle0) / spent), 2)


def wait_for_quiet(label: str = "", patience: float | None = None) -> tuple[float, bool]:
    """The 1-minute load when the sample starts, and whether nothing else ran:
    the first window with fewer than QUIET cores busy within ``patience``."""
    deadline = time.monotonic() + (PATIENCE if patience is None else patience)
    busy = busy_cores()
    told = False
    while busy >= QUIET and time.monotonic() < deadline:
        if not told:
            print(f"[bench] {label}: {busy:.2f} cores busy; waiting for a quiet machine", file=sys.stderr, flush=True)
            told = True
        busy = busy_cores()
    if busy >= QUIET:
        print(
            f"[bench] {label}: still {busy:.2f} cores busy after waiting; this figure is marked loaded",
            file=sys.stderr,
            flush=True,
        )
    return round(load(), 2), busy < QUIET


def wait(label: str, first: bool, patience: float | None = None) -> tuple[float, bool]:
    """Before a sample: (the 1-minute load, whether the sample starts idle)."""
    if first:
        current = wait_for_idle(label, patience=patience)
        return current, current < LIMIT
    return wait_for_quiet(label, patience=patience)


@dataclass
class Figure:
    """Samples of one figure (seconds) and the load before each."""

    samples: list[float] = field(default_factory=list)
    loads: list[float] = field(default_factory=list)
    idles: list[bool] = field(default_factory=list)  # per sample; else judged by its load

    def add(self, seconds: float, load_before: float, idle: bool | None = None) -> float:
        self.samples.append(seconds)
        self.loads.append(load_before)
        self.idles.append(load_before < LIMIT if idle is None else idle)
        return seconds

    @property
    def median(self) -> float | None:
        return statistics.median(self.samples) if self.samples else None

    @property
    def idle(self) -> bool:
        flags = self.idles or [value < LIMIT for value in self.loads]
        return bool(flags) and all(flags)

    def as_dict(self) -> dict:
        return {
            "median": self.median,
            "min": min(self.samples, default=None),
            "max": max(self.samples, default=None),
            "samples": self.samples,
            "loads": self.loads,
            "idles": self.idles,
            "idle": self.idle,
        }


def shown(figure: dict | None) -> str:
    """``median (min–max)``, with the highest load before a sample when it
    was not idle: ``1.23 (1.20–1.31) [load 3.4]``."""
    if not figure or figure.get("median") is None:
        return "-"
    text = f"{figure['median']:.2f}"
    if len(figure["samples"]) > 1:
        text += f" ({figure['min']:.2f}–{figure['max']:.2f})"
    if not figure.get("idle"):
        text += f" [load {max(figure['loads']):.1f}]"
    return text
