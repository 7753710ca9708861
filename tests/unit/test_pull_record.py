"""The release record (robotfleet/pull/protocol/record.py): written and read back
the same, and every bad field refused with one line naming it."""

import datetime
import json

import pytest

from robotfleet.pull.protocol import record, waves

NOW = datetime.datetime(2026, 11, 25, 10, 0, tzinfo=datetime.timezone.utc)
COMMIT = "0123456789abcdef0123456789abcdef01234567"


def built(**changes) -> record.Record:
    made = record.build(
        7,
        NOW,
        NOW + datetime.timedelta(days=30),
        COMMIT,
        "a" * 64,
        "inventories/robots.yaml",
        "b" * 64,
        ["robot1", "robot2"],
        {"robot1": {"reg.lan:5000/ros/payload:1.1": "sha256:" + "c" * 64}},
        {"cp313-x86_64": ["wheels/pyinfra-3.1-py3-none-any.whl"]},
        waves.parse_plan({"canary": "1", "waves": ["50%", "100%"], "pause": 600, "max_failed": "0"}),
    )
    data = made.to_dict()
    data.update(changes)
    return data


def test_a_record_is_written_and_read_back_the_same():
    made = record.parse(json.dumps(built()))
    assert made.version == 7
    assert made.release == "2026-11-25T10:00:00Z-7"
    assert made.code == f"code/{COMMIT}.tar.gz"
    assert made.images_of("robot1") == {"reg.lan:5000/ros/payload:1.1": "sha256:" + "c" * 64}
    assert made.images_of("robot2") == {}
    assert made.wheels_for("cp313-x86_64") == ["wheels/pyinfra-3.1-py3-none-any.whl"]
    assert made.targets() == [made.code, "wheels/pyinfra-3.1-py3-none-any.whl"]
    assert made.published_at == NOW
    assert record.parse(made.to_bytes()) == made
    assert made.to_bytes() == record.parse(made.to_bytes()).to_bytes()  # same record, same bytes


def test_a_halt_is_the_next_version_of_the_same_release():
    made = record.parse(json.dumps(built()))
    later = NOW + datetime.timedelta(hours=1)
    halted = made.halted(8, later, later + datetime.timedelta(days=30), "canary crash-loops")
    assert (halted.version, halted.halt, halted.halt_reason) == (8, True, "canary crash-loops")
    assert (halted.commit, halted.images, halted.robots) == (made.commit, made.images, made.robots)
    assert record.parse(halted.to_bytes()) == halted


@pytest.mark.parametrize(
    "changes, says",
    [
        ({"format": 2}, "release.json: format: expected 1"),
        ({"version": 0}, "release.json: version: expected an integer >= 1, got 0"),
        ({"version": True}, "release.json: version: expected an integer >= 1, got True"),
        ({"version": "7"}, "release.json: version: expected an integer >= 1, got '7'"),
        ({"published": "yesterday"}, "release.json: published: expected a UTC time like 2026-11-25T10:00:00Z"),
        ({"expires": "2026-11-25T09:00:00Z"}, "release.json: expires (2026-11-25T09:00:00Z) is not after published"),
        ({"commit": "HEAD"}, "release.json: commit: expected 40 or 64 lowercase hex digits, got 'HEAD'"),
        ({"tree_sha256": "A" * 64}, "release.json: tree_sha256: expected 64 lowercase hex digits"),
        (
            {"code": "code/other.tar.gz"},
            f"release.json: code: expected the archive of the commit, code/{COMMIT}.tar.gz",
        ),
        ({"fleet": {"path": "../x.yaml", "sha256": "b" * 64}}, "release.json: fleet: expected {path"),
        ({"fleet": {"path": "x.yaml", "sha256": "nope"}}, "release.json: sha256: expected 64 lowercase hex digits"),
        ({"robots": ["robot1", "robot1"]}, "release.json: robots: expected each robot once, got 'robot1'"),
        ({"robots": ["robot 1"]}, "release.json: robots: expected a list of robot names"),
        ({"images": {"robot9": {}}}, "release.json: images.robot9: expected a robot of robots"),
        (
            {"images": {"robot1": {"x:1": "sha256:abc"}}},
            "release.json: images.robot1.x:1: expected sha256:<64 hex digits>",
        ),
        ({"wheels": {"py3-any": []}}, "release.json: wheels.py3-any: expected a platform like cp313-x86_64"),
        (
            {"wheels": {"cp313-x86_64": ["wheels/../../etc/passwd.whl"]}},
            "release.json: wheels.cp313-x86_64[0]: expected a target path wheels/<name>.whl",
        ),
        ({"rollout": {"waves": ["50%"]}}, "release.json: rollout.waves: the last wave must be 100%"),
        ({"rollout": {"canary": "-1"}}, "release.json: rollout.canary: expected a number of robots or a percentage"),
        ({"halt": "yes"}, "release.json: halt: expected true or false, got 'yes'"),
        ({"halt_reason": "two\nlines"}, "release.json: halt_reason: expected one line of text or null"),
        ({"surprise": 1}, "release.json: unknown field 'surprise'"),
    ],
)
def test_each_bad_field_is_one_line_naming_it(changes, says):
    with pytest.raises(record.RecordError) as caught:
        record.parse(json.dumps(built(**changes)))
    assert str(caught.value).startswith(says), str(caught.value)
    assert "\n" not in str(caught.value)


@pytest.mark.parametrize(
    "data, says",
    [
        (b"\xff\xfe", "release.json: not JSON"),
        (b"[1, 2]", "release.json: the record: expected a JSON object, got 'list'"),
        (b"{", "release.json: not JSON"),
    ],
)
def test_what_is_not_a_record_at_all(data, says):
    with pytest.raises(record.RecordError, match="^" + says.replace("(", r"\(").replace("[", r"\[")):
        record.parse(data)
