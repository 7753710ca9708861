"""``python -m robotfleet.pull.agent``: an entry point named by what is already on robots
(robot-pull.service's ExecStart, and the agents of earlier releases, which
run a release's converge by this name), so it never moves; the code is
robotfleet/pull/robot/agent.py."""

import sys

if __name__ == "__main__":
    from robotfleet.pull.robot.agent import main

    sys.exit(main())
