"""The robot's verified refresh against real TUF repositories on disk, with
real ed25519 keys (python-tuf 7, securesystemslib's CryptoSigner): a
release is accepted; unsigned, unknown-key, tampered, rolled-back, expired
and malformed ones are refused with their reason and the robot's trusted
state byte for byte as it was; key rotation is followed; the clock rule."""

from __future__ import annotations

import datetime
import shutil

import pytest

from tests.unit import pullkit
from tests.unit.pullkit import DAY, NOW, edit_json, refused

ceremony = pullkit.module("operator.root_ceremony")
refusals = pullkit.module("robot.refusals")


@pytest.fixture
def trust():
    return pullkit.module("robot.verify")


@pytest.fixture
def fleet(tmp_path):
    made = pullkit.Fleet(tmp_path)
    made.release(1)
    made.trust()
    return made


def test_a_published_release_is_verified_and_its_code_downloaded(fleet, trust, tmp_path):
    client = fleet.client()
    record = client.refresh()
    assert (record.version, record.robots) == (1, ("robot1", "robot2"))
    got = client.download([record.code], tmp_path / "dl")
    assert got[record.code].read_bytes() == b"code of release 1"
    state = trust.read_state(fleet.state)
    assert (state.version, state.release, state.time) == (1, record.release, NOW)
    # a second wake finds the same release, and nothing to download again
    again = fleet.client()
    assert again.refresh().version == 1
    assert again.download([record.code], tmp_path / "dl") == got


def test_what_an_interrupted_refresh_left_is_swept(fleet):
    (fleet.state / "tuf-leftover").mkdir()
    (fleet.state / ".tuf-link-0000").symlink_to("tuf-leftover")
    fleet.refresh()
    current = (fleet.state / "tuf").resolve().name
    assert {p.name for p in fleet.state.iterdir()} == {
        "trust.json",
        "tuf",
        current,
    }


def test_a_new_release_is_accepted_after_the_first(fleet):
    fleet.refresh()
    fleet.release(2)
    assert fleet.refresh().version == 2


def test_a_tampered_record_is_refused(fleet):
    fleet.refresh()
    record = fleet.release(2)
    blob = fleet.repository.blob("release.json")
    blob.write_bytes(blob.read_bytes().replace(b'"halt": false', b'"halt": true '))
    line = refused(fleet, refusals.TAMPERED)
    assert line.startswith(f"releases at {fleet.repository.path}: does not match what was signed ("), line
    assert record.version == 2


def test_tampered_targets_metadata_is_refused(fleet):
    fleet.refresh()
    fleet.release(2)
    targets = fleet.repository.metadata / "3.targets.json"
    edit_json(targets, lambda md: md["signed"]["targets"]["release.json"].update(length=1))
    refused(fleet, refusals.TAMPERED)


def test_a_changed_timestamp_with_the_old_signature_is_refused_as_tampered(fleet):
    fleet.release(2)
    edit_json(
        fleet.repository.metadata / "timestamp.json", lambda md: md["signed"].update(expires="2099-01-01T00:00:00Z")
    )
    line = refused(fleet, refusals.TAMPERED)
    assert line.startswith("timestamp.json: changed after it was signed")


def test_a_tampered_code_archive_is_refused_at_download(fleet, tmp_path):
    client = fleet.client()
    record = client.refresh()
    fleet.repository.blob(record.code).write_bytes(b"evil code")
    with pytest.raises(refusals.Refused) as caught:
        client.download([record.code], tmp_path / "dl")
    assert caught.value.reason == refusals.TAMPERED
    assert not (tmp_path / "dl" / record.code).exists()
    assert not [p for p in (tmp_path / "dl").rglob("*") if p.is_file()]


def test_an_unsigned_timestamp_is_refused(fleet):
    fleet.release(2)
    edit_json(fleet.repository.metadata / "timestamp.json", lambda md: md.update(signatures=[]))
    line = refused(fleet, refusals.UNSIGNED)
    assert line.startswith("timestamp.json: not signed")


def test_a_repository_signed_by_another_key_is_refused(fleet, trust, tmp_path):
    fleet.refresh()
    other = pullkit.Fleet(tmp_path / "other", name="keys")
    other.release(5)
    line = refused(fleet, refusals.UNKNOWN_KEY, source=other.repository.path)
    assert "does not trust" in line


def test_a_timestamp_signed_by_a_key_the_root_does_not_name_is_refused(fleet, tmp_path):
    from tuf.api.metadata import Metadata

    stranger = pullkit.module("operator.keys").KeyDir(tmp_path / "stranger")
    stranger.generate("online")
    path = fleet.repository.metadata / "timestamp.json"
    md = Metadata.from_file(str(path))
    md.signed.version += 1
    md.sign(stranger.signer("online"))
    md.to_file(str(path))
    refused(fleet, refusals.UNKNOWN_KEY)


def test_a_replayed_older_repository_is_refused_as_a_rollback(fleet, tmp_path):
    old = tmp_path / "old-repo"
    shutil.copytree(fleet.repository.path, old)
    fleet.release(2)
    assert fleet.refresh().version == 2
    line = refused(fleet, refusals.ROLLBACK, source=old)
    assert "rollback" in line


def test_a_record_below_the_applied_version_is_a_rollback(fleet):
    line = refused(fleet, refusals.ROLLBACK, applied=3)
    assert line.startswith("release 1 (") and "older than release 3" in line


def test_an_expired_repository_is_refused_as_a_freeze(tmp_path, trust):
    fleet = pullkit.Fleet(tmp_path, now=NOW - 10 * DAY)
    fleet.release(1, now=NOW - 10 * DAY)  # its timestamp (7 days) expired 3 days ago
    fleet.trust()
    line = refused(fleet, refusals.EXPIRED)
    assert "expired" in line and "freeze" in line


def test_expired_targets_metadata_is_refused(fleet):
    expiry = pullkit.module("operator.repository").Expiry(targets=2 * DAY, snapshot=40 * DAY, timestamp=30 * DAY)
    fleet.release(2, expiry=expiry)
    line = refused(fleet, refusals.EXPIRED, clock=lambda: NOW + 3 * DAY)
    assert "expired: refused as a freeze (New targets is expired)" in line


def test_a_record_past_its_own_expiry_is_refused(fleet):
    # every TUF role still valid; the record's own expiry has passed
    fleet.release(2, record_expires=NOW + DAY)
    line = refused(fleet, refusals.EXPIRED, clock=lambda: NOW + 2 * DAY)
    assert line.startswith("release 2 (") and "expired at" in line and "freeze" in line


def test_clock_in_1970_does_not_let_an_expired_repository_through(tmp_path, trust):
    fleet = pullkit.Fleet(tmp_path, now=NOW - 10 * DAY)
    fleet.release(1, now=NOW - 10 * DAY)
    fleet.trust(trusted_time=NOW)  # it once trusted something at NOW (after the timestamp's expiry)
    epoch = datetime.datetime(1970, 1, 1, tzinfo=datetime.timezone.utc)
    refused(fleet, refusals.EXPIRED, clock=lambda: epoch)


def test_clock_in_1970_still_verifies_a_current_repository_and_keeps_the_trusted_time(fleet, trust):
    epoch = datetime.datetime(1970, 1, 1, tzinfo=datetime.timezone.utc)
    record = fleet.refresh(clock=lambda: epoch)
    assert record.version == 1
    assert trust.read_state(fleet.state).time == record.published_at  # never moved back to 1970


def test_a_clock_behind_the_last_trusted_time_is_not_believed(tmp_path, trust):
    fleet = pullkit.Fleet(tmp_path, now=NOW - 10 * DAY)
    fleet.release(1, now=NOW - 10 * DAY)  # valid until NOW - 3 days
    fleet.trust(trusted_time=NOW)
    behind = lambda: NOW - 9 * DAY  # noqa: E731 - by this clock, everything is still valid
    refused(fleet, refusals.EXPIRED, clock=behind)
    # the same robot without the later trusted time accepts it: the refusal was the clock rule
    fleet.trust(trusted_time=None)
    assert fleet.refresh(clock=behind).version == 1


def test_the_private_reference_time_exists_in_this_python_tuf(fleet):
    from tuf.ngclient import Updater

    updater = Updater(str(fleet.state / "tuf"), "file:///nonexistent/", bootstrap=None)
    moment = NOW + 365 * DAY
    pullkit.module("robot.tufprivate").set_reference_time(updater, moment)
    assert updater._trusted_set.reference_time == moment


def test_online_key_rotation_is_followed_by_a_robot_that_trusted_the_old_root(fleet):
    assert fleet.refresh().version == 1
    repository, keys = fleet.repository, fleet.keys
    new_online = keys.generate("online.next")
    unsigned = ceremony.prepare_root(repository, fleet.expiry, NOW, online_key=new_online)
    signed = ceremony.sign_root(unsigned, [keys.signer("root")])
    assert ceremony.install_root(repository, signed, keys.signer("online.next"), fleet.expiry, NOW) == 2
    keys.promote("online.next", "online")
    fleet.release(2)
    assert fleet.refresh().version == 2
    assert (fleet.state / "tuf" / "root_history" / "2.root.json").exists()
    # the old online key can no longer sign for the fleet
    from tuf.api.metadata import Metadata

    path = repository.metadata / "timestamp.json"
    md = Metadata.from_file(str(path))
    md.signed.version += 1
    md.sign(pullkit.module("operator.keys").signer_of(keys.path / "online.old.key"))
    md.to_file(str(path))
    refused(fleet, refusals.UNKNOWN_KEY)


def test_root_key_rotation_is_followed_and_the_old_root_key_alone_cannot_make_a_root(fleet, tmp_path):
    repository, keys = fleet.repository, fleet.keys
    sign_root = ceremony.sign_root
    new_root = keys.generate("root.next")
    unsigned = ceremony.prepare_root(repository, fleet.expiry, NOW, root_key=new_root)
    with pytest.raises(pullkit.module("operator.repository").RepositoryError, match="not signed by its own root key"):
        ceremony.install_root(
            repository, sign_root(unsigned, [keys.signer("root")]), keys.signer("online"), fleet.expiry, NOW
        )
    signed = sign_root(unsigned, [keys.signer("root"), keys.signer("root.next")])
    ceremony.install_root(repository, signed, keys.signer("online"), fleet.expiry, NOW)
    fleet.release(2)
    assert fleet.refresh().version == 2
    # a root version 3 signed only by the replaced root key is refused by the robot
    old_only = sign_root(ceremony.prepare_root(repository, fleet.expiry, NOW), [keys.signer("root")])
    (repository.metadata / "3.root.json").write_bytes(old_only)
    line = refused(fleet, refusals.UNKNOWN_KEY)
    assert line.startswith("root.json")


def test_the_operator_side_refuses_to_sign_with_an_online_key_the_root_does_not_name(fleet, tmp_path):
    repository = pullkit.module("operator.repository")
    stranger = pullkit.module("operator.keys").KeyDir(tmp_path / "stranger")
    stranger.generate("online")
    for attempt in (
        lambda: fleet.repository.renew(stranger.signer("online"), fleet.expiry, NOW),
        lambda: fleet.repository.resign(stranger.signer("online"), fleet.expiry, NOW),
    ):
        with pytest.raises(repository.RepositoryError, match="is not the one the repository's root names"):
            attempt()
    assert fleet.refresh().version == 1


def test_an_unsigned_prepared_root_is_not_installed(fleet):
    repository = pullkit.module("operator.repository")
    unsigned = ceremony.prepare_root(fleet.repository, fleet.expiry, NOW)
    with pytest.raises(repository.RepositoryError, match="not signed by the current root key"):
        ceremony.install_root(fleet.repository, unsigned, fleet.keys.signer("online"), fleet.expiry, NOW)
    assert fleet.repository.root().signed.version == 1


def test_garbage_metadata_is_malformed(fleet):
    (fleet.repository.metadata / "timestamp.json").write_text("{not json")
    refused(fleet, refusals.MALFORMED)


def test_a_signed_release_json_that_is_not_a_record_is_malformed(fleet, tmp_path):
    from tuf.api.metadata import TargetFile

    repository = fleet.repository
    targets = repository.targets()
    bogus = tmp_path / "bogus.json"
    bogus.write_bytes(b'{"format": 1, "version": "seven"}')
    info = TargetFile.from_file("release.json", str(bogus), ["sha256"])
    stored = repository.targets_dir / f"{info.hashes['sha256']}.release.json"
    shutil.copy(bogus, stored)
    targets.signed.targets["release.json"] = info
    repository._publish_targets(targets, fleet.keys.signer("online"), fleet.expiry, NOW)
    line = refused(fleet, refusals.MALFORMED)
    assert line.startswith("release.json: version: expected an integer")


def test_a_missing_repository_is_unavailable(fleet, tmp_path):
    (tmp_path / "empty").mkdir()
    line = refused(fleet, refusals.UNAVAILABLE, source=tmp_path / "empty")
    assert "timestamp.json" in line


def test_a_robot_without_a_trusted_root_refuses(tmp_path, trust):
    with pytest.raises(refusals.Refused, match="no trusted root"):
        trust.Client(tmp_path / "nothing", str(tmp_path)).refresh()


def test_initialize_refuses_a_root_that_is_not_self_signed(fleet, trust, tmp_path):
    data = ceremony.prepare_root(fleet.repository, fleet.expiry, NOW)  # unsigned
    with pytest.raises(refusals.Refused, match="not a self-signed TUF root") as caught:
        trust.initialize(tmp_path / "robot2", data)
    assert caught.value.reason == refusals.MALFORMED


def test_the_repository_is_verified_over_http(fleet):
    with pullkit.static_http(fleet.repository.path) as url:
        client = fleet.client(source=url)
        record = client.refresh()
        got = client.download([record.code], fleet.base / "dl")
    assert record.version == 1 and got[record.code].read_bytes() == b"code of release 1"


def test_a_directory_source_serves_nothing_outside_it(fleet, trust, tmp_path):
    fetcher = trust.DirectoryFetcher(fleet.repository.path)
    from tuf.api import exceptions

    outside = tmp_path / "secret"
    outside.write_text("x")
    with pytest.raises(exceptions.DownloadHTTPError):
        list(fetcher._fetch(f"file://{fleet.repository.path}/metadata/../../secret"))


def test_a_link_in_the_repository_is_not_followed(fleet):
    # even to a file inside it (a checkout never holds links; a mirror's copy might)
    metadata = fleet.repository.metadata
    (metadata / "timestamp.json").rename(metadata / "elsewhere.json")
    (metadata / "timestamp.json").symlink_to("elsewhere.json")
    line = refused(fleet, refusals.UNAVAILABLE)
    assert "timestamp.json: a symbolic link, not read" in line


@pytest.mark.parametrize("flooded", ["metadata/timestamp.json", "the record"])
def test_an_endless_answer_of_a_mirror_is_read_only_to_its_cap(fleet, flooded):
    if flooded == "the record":
        flooded = next(
            f"targets/{p.name}"
            for p in (fleet.repository.path / "targets").iterdir()
            if p.name.endswith(".release.json")
        )
    with pullkit.Flood(fleet.repository.path, flooded) as mirror:
        line = refused(fleet, refusals.TAMPERED, source=mirror.url)
    assert "longer than what was signed" in line
    assert mirror.sent < 24 << 20  # of 64 MiB: the signed length (or the role's cap) and the sockets' buffers
