"""``python -m robotfleet.pull.agent``: an entry point named by what is already on robots
(robot-pull.service's ExecStart before robotfleet/pull/start.py, and the agents of
earlier releases, which run a release's converge by this name), so it never moves;
the code is robotfleet/pull/robot/agent.py.  First the idle check
(robotfleet/pull/robot/idle.py): a wake that finds nothing new ends there,
without importing the agent."""

import sys

from robotfleet.pull.start import main

if __name__ == "__main__":
    sys.exit(main())
