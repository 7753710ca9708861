"""The caps a mirror's files are read by (robotfleet/pull/robot/fetched.py): one
for each kind of TUF metadata, the same as python-tuf's own defaults."""

from __future__ import annotations

import pytest

from robotfleet.pull.robot import fetched


@pytest.mark.parametrize(
    "name, cap",
    [
        ("metadata/2.root.json", 512000),
        ("root.json", 512000),
        ("metadata/timestamp.json", 16384),
        ("metadata/7.snapshot.json", 2000000),
        ("snapshot.json", 2000000),
        ("metadata/7.targets.json", 5000000),
        ("metadata/3.some-delegated-role.json", 5000000),
    ],
)
def test_each_kind_of_metadata_has_its_cap(name, cap):
    assert fetched.metadata_max(name) == cap


def test_the_caps_are_python_tuf_s_defaults():
    from tuf.ngclient import UpdaterConfig

    defaults = UpdaterConfig()
    assert (fetched.ROOT_MAX, fetched.TIMESTAMP_MAX, fetched.SNAPSHOT_MAX, fetched.TARGETS_MAX) == (
        defaults.root_max_length,
        defaults.timestamp_max_length,
        defaults.snapshot_max_length,
        defaults.targets_max_length,
    )
