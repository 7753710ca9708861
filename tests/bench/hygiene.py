"""Benchmark hygiene: a figure is taken on an idle machine or says it was not.

Every benchmark here calls ``wait_for_idle`` before each figure it times:
it waits (up to ``patience`` seconds) for the 1-minute load average to fall
below ``LIMIT`` and returns the load it started at, which goes next to the
figure.  ``Figure`` keeps the samples (at least ``MIN_SAMPLES``) with their
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
            print(f"[bench] {label}: load average {current:.2f} >= {limit}; waiting for an idle machine",
                  file=sys.stderr, flush=True)
            told = True
        time.sleep(poll)
        current = load()
    if current >= limit:
        print(f"[bench] {label}: still {current:.2f} after waiting; this figure is marked loaded",
              file=sys.stderr, flush=True)
    return round(current, 2)


@dataclass
class Figure:
    """Samples of one figure (seconds) and the load before each."""

    samples: list[float] = field(default_factory=list)
    loads: list[float] = field(default_factory=list)

    def add(self, seconds: float, load_before: float) -> float:
        self.samples.append(seconds)
        self.loads.append(load_before)
        return seconds

    @property
    def median(self) -> float | None:
        return statistics.median(self.samples) if self.samples else None

    @property
    def idle(self) -> bool:
        return bool(self.loads) and max(self.loads) < LIMIT

    def as_dict(self) -> dict:
        return {"median": self.median, "min": min(self.samples, default=None), "max": max(self.samples, default=None),
                "samples": self.samples, "loads": self.loads, "idle": self.idle}


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
