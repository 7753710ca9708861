"""``python -m robotfleet.pull.agent``: an entry point named by what is already on robots
(robot-pull.service's ExecStart, and the agents of earlier releases, which
run a release's converge by this name), so it never moves; the code is
robotfleet/pull/robot/agent.py."""

import os
import shutil
import sys

import robotfleet

# robot-pull.service names a directory for the agent's bytecode
# (agent_files.PYCACHE): compiling its modules again at every check was most
# of an idle check's CPU, and the release's tree itself takes none (its
# content hash is checked).  One directory per tree, named by the tree's
# own (content-addressed, never rewritten) directory, so a release's code
# never runs from another's bytecode; other trees' go when a new tree starts.
PYCACHE_VARIABLE = "ROBOT_PULL_PYCACHE"


def use_bytecode_cache(where: str | None = None) -> str | None:
    """Compile into ``where``/<tree> from here on; that directory, or None."""
    where = where or os.environ.get(PYCACHE_VARIABLE)
    if not where or not os.path.isabs(where):
        return None
    cache = os.path.join(where, robotfleet.CHECKOUT.name)
    if not os.path.isdir(cache):
        os.makedirs(where, mode=0o700, exist_ok=True)
        for entry in os.listdir(where):  # other trees' (their names: sha256 hex)
            if len(entry) == 64 and all(c in "0123456789abcdef" for c in entry):
                shutil.rmtree(os.path.join(where, entry), ignore_errors=True)
        os.makedirs(cache, mode=0o700)
    sys.pycache_prefix, sys.dont_write_bytecode = cache, False
    return cache


if __name__ == "__main__":
    use_bytecode_cache()
    from robotfleet.pull.robot.agent import main

    sys.exit(main())
