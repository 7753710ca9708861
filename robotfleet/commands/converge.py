"""``python -m robotfleet.commands.converge``: an entry point named by what is already on robots
(robot-pull.service's ExecStart, and the agents of earlier releases, which
run a release's converge by this name), so it never moves; the code is
robotfleet/pull/robot/converge.py."""

import sys

from robotfleet.pull.robot import window_switch
from robotfleet.pull.robot.converge import main

if __name__ == "__main__":
    sys.exit(main(more={"prepare": window_switch.prepare}))
