"""robot-pull.service's start (agent_files.start_command): python -S -c,
which an idle check pays less for than ``python -m robotfleet.pull.agent``:
no `runpy` (with `importlib.util` and `contextlib`) and no `site`, which
idle.leave adds only when the full wake follows (~0.01 s of a robot's CPU
a check).  The unit runs it only where the tree it starts in has this file;
in an older tree it starts ``python -m robotfleet.pull.agent`` as before."""

from __future__ import annotations

import sys

import robotfleet.pull.robot.bytecode  # noqa: F401 (first: the agent's modules are compiled into its directory)
from robotfleet.pull.robot import idle


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    done = idle.check(argv)
    if done is None:
        idle.leave()
        from robotfleet.pull.robot.agent import main as wake

        done = wake(argv)
    return done
