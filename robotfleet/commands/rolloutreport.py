"""What a rollout prints: one line per robot as its wave ends (its outcome
and why), the fleet's table and the summary at the end (one row per robot,
counts that add up to the robots of the rollout).  Everything a robot
supplies (its errors, release ids, image and container names) and every
line of the deploy's output passed on is escaped for the terminal: control
characters are shown (\\x1b), never obeyed."""

from __future__ import annotations

import sys

from robotfleet.checkers import one_line
from robotfleet.commands import rollout_plan as waves


def say(text: str) -> None:
    """A line of the rollout's log, on stderr."""
    print(one_line(text), file=sys.stderr, flush=True)


def relay(line: str) -> None:
    """A line of the deploy's own output (pyinfra's, with what robots sent), passed on."""
    sys.stderr.write(one_line(line.rstrip("\r\n")) + "\n")
    sys.stderr.flush()


def robot_line(state: dict, host: str) -> str:
    """``rollout: [robot2] failed: why``: a robot's outcome once its wave ends."""
    why = waves.reason(state, host)
    return f"rollout: [{host}] {waves.outcome(state, host)}" + (f": {why}" if why else "")


def table(rows: dict[str, dict], state: dict) -> str:
    """One row per robot of the rollout: its wave, outcome, release, images."""
    robots = [h for wave in state["waves"] for h in wave]
    cells = [("HOST", "WAVE", "OUTCOME", "RELEASE", "IMAGE")]
    for index, wave in enumerate(state["waves"]):
        for host in wave:
            row = rows.get(host) or {}
            image = ", ".join(row.get("image_refs") or []) or ("unreachable" if not row.get("reachable") else "-")
            cells.append(
                (
                    host,
                    f"{index + 1}/{len(state['waves'])}",
                    waves.outcome(state, host),
                    row.get("release") or "-",
                    image,
                )
            )
    cells = [tuple(one_line(str(cell)) for cell in line) for line in cells]
    widths = [max(len(line[i]) for line in cells) for i in range(len(cells[0]))]
    assert len(cells) == len(robots) + 1
    return "\n".join("  " + "  ".join(c.ljust(w) for c, w in zip(line, widths)).rstrip() for line in cells)


def summary(state: dict) -> str:
    return one_line(waves.summary(state))
