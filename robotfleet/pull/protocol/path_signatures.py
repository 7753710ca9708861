"""What lstat says of a few paths, to compare from one check to the next
(the roles' watched paths, robotfleet/pull/protocol/agent_files.py)."""

from __future__ import annotations

import os
import stat


def watched(paths) -> dict[str, str]:
    """path -> what lstat (and readlink, for a link) says of it now, "-"
    when it is not there: compared at each check, it says whether what the
    roles' status reads may have changed (no process, no import)."""
    found = {}
    for path in sorted(set(paths)):
        try:
            info = os.lstat(path)
        except OSError:
            found[path] = "-"
            continue
        said = f"{info.st_ino}:{info.st_mtime_ns}:{info.st_size}"
        if stat.S_ISLNK(info.st_mode):
            try:
                said += ":" + os.readlink(path)
            except OSError:
                pass
        found[path] = said
    return found
