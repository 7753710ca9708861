"""The caps a mirror's files are read by (robotfleet/pull/robot/fetched.py): one
for each kind of TUF metadata, the same as python-tuf's own defaults."""

from __future__ import annotations

from robotfleet.pull.robot import fetched


def test_the_caps_are_python_tuf_s_defaults():
    from tuf.ngclient import UpdaterConfig

    defaults = UpdaterConfig()
    assert (fetched.ROOT_MAX, fetched.TIMESTAMP_MAX, fetched.SNAPSHOT_MAX, fetched.TARGETS_MAX) == (
        defaults.root_max_length,
        defaults.timestamp_max_length,
        defaults.snapshot_max_length,
        defaults.targets_max_length,
    )
