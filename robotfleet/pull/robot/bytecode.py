"""The pull agent's bytecode, compiled once and kept outside the release's tree.

robot-pull.service names a directory for it (agent_files.PYCACHE, in
ROBOT_PULL_PYCACHE): compiling the agent's modules again at every check was
the largest part of an idle check's CPU, and the release's tree itself
takes none (its content hash is checked, and it runs with
PYTHONDONTWRITEBYTECODE).  One directory per tree, named by the tree's own
directory (content-addressed, never rewritten), so a release's code never
runs from another's bytecode; other trees' go when a new tree starts.
Imported first by the entry point (robotfleet/pull/agent.py), which is what
sets it up; with no ROBOT_PULL_PYCACHE (tests, a checkout) it does nothing.
"""

import os
import sys

import robotfleet

VARIABLE = "ROBOT_PULL_PYCACHE"


def use(where: str | None = None) -> str | None:
    """Compile into ``where``/<tree> from here on; that directory, or None."""
    where = where or os.environ.get(VARIABLE)
    if not where or not os.path.isabs(where):
        return None
    cache = os.path.join(where, os.path.basename(robotfleet.CHECKOUT_DIR))
    try:
        fresh = not os.path.isdir(cache)
        if fresh:
            os.makedirs(where, mode=0o700, exist_ok=True)
            os.makedirs(cache, mode=0o700, exist_ok=True)  # a check started by hand may make it first
    except OSError:  # a full disk, a broken path: the check runs, compiling as before
        return None
    sys.pycache_prefix, sys.dont_write_bytecode = cache, False
    if fresh:  # a new tree: the others' go (shutil imported now, compiled into the new directory)
        import shutil

        try:
            for entry in os.listdir(where):  # other trees' (their names: sha256 hex)
                if (
                    len(entry) == 64
                    and all(c in "0123456789abcdef" for c in entry)
                    and entry != os.path.basename(cache)
                ):
                    shutil.rmtree(os.path.join(where, entry), ignore_errors=True)
        except OSError:
            pass
    return cache


use()
