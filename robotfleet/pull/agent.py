"""``python -m robotfleet.pull.agent``: an entry point named by what is already on robots
(robot-pull.service's ExecStart, and the agents of earlier releases, which
run a release's converge by this name), so it never moves; the code is
robotfleet/pull/robot/agent.py.  First the idle check
(robotfleet/pull/robot/idle.py): a wake that finds nothing new ends there,
without importing the agent."""

import sys

import robotfleet.pull.robot.bytecode  # noqa: F401 (first: the agent's modules are compiled into its directory)
from robotfleet.pull.robot import idle

if __name__ == "__main__":
    done = idle.check(sys.argv[1:])
    if done is None:
        idle.leave()
        from robotfleet.pull.robot.agent import main

        done = main()
    sys.exit(done)
