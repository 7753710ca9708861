"""A check that finds the repository exactly as its last full verification
did needs no TUF refresh (robotfleet/pull/robot/trust_state.py): the record comes
back without python-tuf; any change to what a refresh reads, a new root,
time past an expiry, or a version below the one applied sends the check
to the full refresh, which judges it (and refuses what it refuses).  Real
repositories and keys on disk, and over a static HTTP server."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from robotfleet.pull.robot import trust_state
from tests.unit import pullkit
from tests.unit.pullkit import DAY, NOW, edit_json


@pytest.fixture
def fleet(tmp_path):
    made = pullkit.Fleet(tmp_path)
    made.release(1)
    made.trust()
    made.refresh()
    return made


def recall(fleet, now=NOW, source=None, applied=0):
    found = trust_state.recall(fleet.state, str(source or fleet.repository.path), now, applied)
    return found[0] if found else None


def test_the_same_repository_gives_the_verified_record_back(fleet):
    record = recall(fleet)
    assert (record.version, record.robots) == (1, ("robot1", "robot2"))
    # later, the clock moves the trusted time on, as a successful check does
    assert trust_state.recall(fleet.state, str(fleet.repository.path), NOW + DAY)[1] == NOW + DAY
    assert trust_state.read_state(fleet.state).time == NOW + DAY
    # a clock behind the trusted time is not believed
    assert trust_state.recall(fleet.state, str(fleet.repository.path), NOW)[1] == NOW + DAY


def test_recalling_imports_no_tuf(fleet):
    code = (
        "import sys, datetime; from robotfleet.pull.robot import trust_state; "
        f"found = trust_state.recall({str(fleet.state)!r}, {str(fleet.repository.path)!r}, "
        "datetime.datetime.now(datetime.timezone.utc)); "
        "assert found and found[0].version == 1, found; "
        "print(sorted(m for m in sys.modules if m.split('.')[0] in ('tuf', 'securesystemslib', 'urllib3')))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "[]"


@pytest.mark.parametrize("change", ["timestamp", "record", "next root", "new release"])
def test_any_change_to_what_a_refresh_reads_means_a_full_refresh(fleet, change):
    repo = fleet.repository
    if change == "timestamp":
        edit_json(repo.metadata / "timestamp.json", lambda d: d["signed"].update(version=d["signed"]["version"] + 1))
    elif change == "record":
        blob = repo.blob("release.json")
        blob.write_bytes(blob.read_bytes().replace(b'"halt": false', b'"halt": true '))
    elif change == "next root":
        (repo.metadata / "2.root.json").write_text("{}")
    else:
        fleet.release(2)
    assert recall(fleet) is None


def test_an_expiry_a_rollback_floor_or_another_source_means_a_full_refresh(fleet, tmp_path):
    expires = min(fleet.repository.timestamp().signed.expires, fleet.repository.record().expires_at)
    assert recall(fleet, now=expires - DAY) is not None
    assert recall(fleet, now=expires) is None
    assert recall(fleet, applied=2) is None
    assert recall(fleet, source=tmp_path / "elsewhere") is None


def test_an_initialized_trust_forgets_what_it_verified(fleet):
    fleet.trust()
    assert recall(fleet) is None
    assert not (fleet.state / trust_state.VERIFIED).exists()


def test_over_http_the_same_files_are_read(fleet):
    with pullkit.static_http(fleet.repository.path) as url:
        fleet.refresh(source=url)
        assert recall(fleet, source=url).version == 1
        fleet.release(2)
        assert recall(fleet, source=url) is None
        assert fleet.refresh(source=url).version == 2
        assert recall(fleet, source=url).version == 2


# -- a hostile mirror or git server: links and endless files --------------------------------------------------------


def reads(fleet) -> list[str]:
    """What the last full verification read, as the next check reads it."""
    return json.loads((fleet.state / trust_state.VERIFIED).read_text())["reads"]


def test_a_link_to_dev_zero_is_not_read(fleet):
    # The repository as a mirror (or a checkout made with links) might hold it.
    (fleet.repository.metadata / "2.root.json").symlink_to("/dev/zero")
    # In a process of bounded memory: reading /dev/zero would end in MemoryError.
    code = (
        "import resource, sys; resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30)); "
        "from robotfleet.pull.robot import trust_state as t; print(t.fingerprint(sys.argv[1], sys.argv[2:]))"
    )
    done = subprocess.run(
        [sys.executable, "-c", code, str(fleet.repository.path), *reads(fleet)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert (done.returncode, done.stdout.strip()) == (0, "None"), done.stderr[-2000:]
    with pytest.raises(OSError, match="2.root.json: a symbolic link, not read"):
        trust_state.read(str(fleet.repository.path), "metadata/2.root.json")
    assert recall(fleet) is None


@pytest.mark.parametrize("plant", ["link to a file outside", "linked directory", "fifo", "too large"])
def test_what_is_not_a_regular_file_within_its_cap_is_refused(fleet, tmp_path, plant):
    secret = tmp_path / "hostname"
    secret.write_text("robot-secret\n")
    metadata = fleet.repository.metadata
    if plant == "link to a file outside":
        (metadata / "timestamp.json").unlink()
        (metadata / "timestamp.json").symlink_to(secret)
        says = "timestamp.json: a symbolic link, not read"
    elif plant == "linked directory":
        elsewhere = tmp_path / "elsewhere"
        metadata.rename(elsewhere)
        metadata.symlink_to(elsewhere)
        says = "metadata: a symbolic link, not read"
    elif plant == "fifo":
        (metadata / "timestamp.json").unlink()
        os.mkfifo(metadata / "timestamp.json")  # opening it to read would wait for a writer
        says = "timestamp.json: not a regular file"
    else:
        (metadata / "timestamp.json").write_bytes(b" " * 16385)  # python-tuf's cap is 16384
        says = "timestamp.json: larger than 16384 bytes"
    with pytest.raises(OSError, match=says):
        trust_state.read(str(fleet.repository.path), "metadata/timestamp.json")
    assert recall(fleet) is None


def test_an_endless_answer_of_a_mirror_is_read_only_to_its_cap(fleet):
    with pullkit.Flood(fleet.repository.path, "metadata/timestamp.json") as mirror:
        assert trust_state.fingerprint(mirror.url, reads(fleet)) is None
        with pytest.raises(OSError, match="timestamp.json: larger than 16384 bytes"):
            trust_state.read(mirror.url, "metadata/timestamp.json")
    assert mirror.sent < 24 << 20  # of 64 MiB: what the sockets' buffers took, no more
