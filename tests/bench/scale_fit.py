"""The scaling benchmark's arithmetic and plot (tests/bench/scale.py):
medians with their spread, a straight-line fit against N, the figure."""

from __future__ import annotations

import statistics
from pathlib import Path


def fit(points: list[tuple[int, float]]) -> dict:
    """Least squares y = a + b N, and the largest relative residual."""
    xs, ys = [p[0] for p in points], [p[1] for p in points]
    mx, my = statistics.fmean(xs), statistics.fmean(ys)
    sxx = sum((x - mx) ** 2 for x in xs)
    b = sum((x - mx) * (y - my) for x, y in points) / sxx if sxx else 0.0
    a = my - b * mx
    worst = max(abs(y - (a + b * x)) / y for x, y in points if y) if points else 0.0
    return {"a": round(a, 4), "b_per_host": round(b, 5), "worst_relative_residual": round(worst, 3)}


def plot(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.2))
    for kind, style in (("noop", "o-"), ("status", "s--")):
        rows = result["curve"][kind]
        ns = [r["hosts"] for r in rows]
        left.errorbar(
            ns,
            [r["seconds"]["median"] for r in rows],
            yerr=[
                [r["seconds"]["median"] - r["seconds"]["min"] for r in rows],
                [r["seconds"]["max"] - r["seconds"]["median"] for r in rows],
            ],
            fmt=style,
            capsize=3,
            label=f"{kind} (fit {result['fits'][kind]['seconds']['a']:.2f} s + "
            f"{result['fits'][kind]['seconds']['b_per_host'] * 1000:.1f} ms/host)",
        )
        right.plot(
            ns,
            [r["peak_rss_mb"]["median"] for r in rows],
            style,
            label=f"{kind} (fit {result['fits'][kind]['peak_rss_mb']['a']:.0f} MB + "
            f"{result['fits'][kind]['peak_rss_mb']['b_per_host']:.2f} MB/host)",
        )
    left.set(xlabel="robots (N)", ylabel="wall time (s)", title="Operator: time against N")
    right.set(xlabel="robots (N)", ylabel="peak resident memory (MB)", title="Operator: memory against N")
    for axis in (left, right):
        axis.grid(True, alpha=0.3)
        axis.legend(fontsize=8)
    fig.suptitle(
        f"No-op rerun and status, one operator process ({result['conditions']['date']}, "
        f"load {result['conditions']['load_range']})",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def summarize(values: list[float]) -> dict:
    return {"median": statistics.median(values), "min": min(values), "max": max(values)}
