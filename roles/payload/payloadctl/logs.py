"""ROS logs kept under a size: the oldest files go first (what the
`<payload>-ros-logs.timer` runs every 10 minutes, roles/payload/ros_logs.py)."""

import os


def files_oldest_first(directory, suffix=None):
    """[(mtime, size, path)] of the regular files under ``directory`` (those
    whose names end with ``suffix`` when given), oldest first (links are not followed)."""
    found = []
    for root, _dirs, names in os.walk(directory):
        for name in names:
            if suffix and not name.endswith(suffix):
                continue
            path = os.path.join(root, name)
            try:
                st = os.lstat(path)
            except OSError:  # gone meanwhile (a node rotating its log)
                continue
            if not os.path.islink(path) and os.path.isfile(path):
                found.append((st.st_mtime, st.st_blocks * 512, path))
    return sorted(found)


def prune(directory, max_bytes, suffix=None):
    """Remove the oldest files until those left take at most ``max_bytes``,
    then the directories left empty (``latest``, a dangling link, goes with
    the run it named).  With ``suffix`` (bags: ".bag") only such files count
    and go, and nothing else is touched: the directory is the user's, who
    may keep other things there.  Returns (files removed, bytes freed)."""
    found = files_oldest_first(directory, suffix)
    total = sum(size for _, size, _ in found)
    removed, freed = 0, 0
    for _mtime, size, path in found:
        if total - freed <= max_bytes:
            break
        try:
            os.unlink(path)
        except OSError:
            continue
        removed, freed = removed + 1, freed + size
    if suffix:
        return removed, freed
    for root, _dirs, _names in os.walk(directory, topdown=False):
        if root != directory and not os.listdir(root):
            os.rmdir(root)
    for root, dirs, names in os.walk(directory):
        for name in dirs + names:
            path = os.path.join(root, name)
            if os.path.islink(path) and not os.path.exists(path):
                os.unlink(path)
    return removed, freed


def main(directory, max_mb, suffix=None):
    if not os.path.isdir(directory):
        return 0
    removed, freed = prune(directory, max_mb * 1024 * 1024, suffix)
    if removed:
        print(
            "payload: {} over {} MB: removed the {} oldest files ({:.1f} MB)".format(
                directory, max_mb, removed, freed / 1048576
            )
        )
    return 0
