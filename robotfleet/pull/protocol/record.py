"""The release record (the TUF target ``release.json``): what one release
binds, in one signed document.  Pure: building, writing and reading it.

    {"format": 1, "version": 7, "release": "2026-11-25T10:00:00Z-7",
     "published": "2026-11-25T10:00:00Z", "expires": "2026-12-25T10:00:00Z",
     "commit": "<git sha>", "tree_sha256": "<robotfleet/pull/protocol/tree.py's hash>",
     "code": "code/<commit>.tar.gz",
     "fleet": {"path": "inventories/robots.yaml", "sha256": "..."},
     "robots": ["robot1", ...],
     "images": {"robot1": {"reg/ros/payload:1.1": "sha256:..."}},
     "wheels": {"cp313-x86_64": ["wheels/...whl", ...]},
     "rollout": {"canary": "1", "waves": ["50%", "100%"], "pause": 600, "max_failed": "0"},
     "halt": false, "halt_reason": null}

``version`` rises with every publish, a halt included; a robot applies a
version only above the one it applied.  Times are UTC, RFC 3339 with a Z.
Every problem reading a record is one line (RecordError) naming the field.
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import re
from dataclasses import dataclass, field

from robotfleet.pull.protocol import waves

FORMAT = 1
NAME = "release.json"  # its TUF target path
MAX_BYTES = 16 << 20
_HEX = re.compile(r"[0-9a-f]+")
_DIGEST = re.compile(r"sha256:[0-9a-f]{64}")
_PLATFORM = re.compile(r"cp3[0-9]{1,2}-[a-z0-9_]+")
_ROBOT = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,252}")
_TIME = "%Y-%m-%dT%H:%M:%SZ"
_TIME_TEXT = re.compile(r"(\d{4})-(\d{1,2})-(\d{1,2})T(\d{1,2}):(\d{1,2}):(\d{1,2})Z", re.ASCII)
FIELDS = (
    "format",
    "version",
    "release",
    "published",
    "expires",
    "commit",
    "tree_sha256",
    "code",
    "fleet",
    "robots",
    "images",
    "wheels",
    "rollout",
    "halt",
    "halt_reason",
)


class RecordError(ValueError):
    """A record that cannot be used; the message is one line."""


def utc(moment: datetime.datetime) -> str:
    """An aware time -> '2026-11-25T10:00:00Z'."""
    return moment.astimezone(datetime.timezone.utc).strftime(_TIME)


def parse_time(text, where: str) -> datetime.datetime:
    """'2026-11-25T10:00:00Z' -> an aware UTC time; RecordError otherwise."""
    # what strptime(_TIME) accepts, in ASCII digits
    match = _TIME_TEXT.fullmatch(text) if isinstance(text, str) else None
    try:
        if match is None:
            raise ValueError(text)
        return datetime.datetime(*map(int, match.groups()), tzinfo=datetime.timezone.utc)
    except ValueError:
        raise RecordError(f"{NAME}: {where}: expected a UTC time like 2026-11-25T10:00:00Z, got {text!r}") from None


@dataclass(frozen=True)
class Record:
    version: int
    release: str
    published: str
    expires: str
    commit: str
    tree_sha256: str
    code: str
    fleet: dict
    robots: tuple[str, ...]
    images: dict = field(default_factory=dict)
    wheels: dict = field(default_factory=dict)
    rollout: waves.Plan = waves.Plan()
    halt: bool = False
    halt_reason: str | None = None

    @property
    def published_at(self) -> datetime.datetime:
        return parse_time(self.published, "published")

    @property
    def expires_at(self) -> datetime.datetime:
        return parse_time(self.expires, "expires")

    def images_of(self, robot: str) -> dict[str, str]:
        """Image reference -> digest, for ``robot`` (empty if none)."""
        return dict(self.images.get(robot, {}))

    def wheels_for(self, platform: str) -> list[str]:
        """The wheel targets for ``platform`` ("cp313-x86_64"; empty if none)."""
        return list(self.wheels.get(platform, []))

    def targets(self) -> list[str]:
        """Every TUF target the record names besides itself: the code archive, the wheels."""
        return [self.code] + sorted({w for files in self.wheels.values() for w in files})

    def to_dict(self) -> dict:
        return {
            "format": FORMAT,
            "version": self.version,
            "release": self.release,
            "published": self.published,
            "expires": self.expires,
            "commit": self.commit,
            "tree_sha256": self.tree_sha256,
            "code": self.code,
            "fleet": dict(self.fleet),
            "robots": list(self.robots),
            "images": {r: dict(i) for r, i in self.images.items()},
            "wheels": {p: list(w) for p, w in self.wheels.items()},
            "rollout": self.rollout.to_dict(),
            "halt": self.halt,
            "halt_reason": self.halt_reason,
        }

    def to_bytes(self) -> bytes:
        """The record as written: sorted keys, one trailing newline (same record, same bytes)."""
        return (json.dumps(self.to_dict(), indent=1, sort_keys=True) + "\n").encode()

    def halted(self, version: int, published: datetime.datetime, expires: datetime.datetime, reason: str) -> Record:
        """The halt of this release: a later version, same contents, ``halt`` true."""
        return dataclasses.replace(
            self,
            version=version,
            release=release_id(published, version),
            published=utc(published),
            expires=utc(expires),
            halt=True,
            halt_reason=reason or "halted",
        )


def release_id(published: datetime.datetime, version: int) -> str:
    return f"{utc(published)}-{version}"


def code_path(commit: str) -> str:
    return f"code/{commit}.tar.gz"


def build(
    version: int,
    published: datetime.datetime,
    expires: datetime.datetime,
    commit: str,
    tree_sha256: str,
    fleet_path: str,
    fleet_sha256: str,
    robots: list[str],
    images: dict[str, dict[str, str]],
    wheels: dict[str, list[str]],
    rollout: waves.Plan,
) -> Record:
    """A new record, checked as a robot will read it (RecordError if not)."""
    record = Record(
        version=version,
        release=release_id(published, version),
        published=utc(published),
        expires=utc(expires),
        commit=commit,
        tree_sha256=tree_sha256,
        code=code_path(commit),
        fleet={"path": fleet_path, "sha256": fleet_sha256},
        robots=tuple(robots),
        images=images,
        wheels=wheels,
        rollout=rollout,
    )
    return parse(record.to_bytes())


def _fail(where: str, expected: str, got) -> RecordError:
    shown = repr(got)
    return RecordError(f"{NAME}: {where}: expected {expected}, got {shown if len(shown) < 80 else shown[:75] + '...'}")


def _hex(raw: dict, key: str, lengths: tuple[int, ...]) -> str:
    value = raw.get(key)
    if not isinstance(value, str) or len(value) not in lengths or not _HEX.fullmatch(value):
        raise _fail(key, f"{' or '.join(map(str, lengths))} lowercase hex digits", value)
    return value


def _target_path(value, where: str, prefix: str, suffix: str) -> str:
    if (
        not isinstance(value, str)
        or not value.startswith(prefix)
        or not value.endswith(suffix)
        or "/" in value[len(prefix) :]
        or value[len(prefix) :] in ("", ".", "..")
        or "\\" in value
    ):
        raise _fail(where, f"a target path {prefix}<name>{suffix}", value)
    return value


def load_json(data: bytes | str, name: str, max_bytes: int, error: type[Exception]):
    """A signed JSON document's bytes, decoded: ``error`` with one line when
    it is larger than ``max_bytes`` or not JSON (release.json, media.json)."""
    if len(data) > max_bytes:
        raise error(f"{name}: larger than {max_bytes >> 20} MiB")
    try:
        return json.loads(data)
    except (ValueError, UnicodeDecodeError) as failure:
        raise error(f"{name}: not JSON ({str(failure).splitlines()[0]})") from None


def parse(data) -> Record:
    """``release.json``'s bytes (or its decoded mapping) -> Record; RecordError (one line) otherwise."""
    if isinstance(data, (bytes, str)):
        data = load_json(data, NAME, MAX_BYTES, RecordError)
    if not isinstance(data, dict):
        raise _fail("the record", "a JSON object", type(data).__name__)
    if data.get("format") != FORMAT:
        raise _fail("format", f"{FORMAT} (a newer robotfleet wrote this record?)", data.get("format"))
    unknown = sorted(set(data) - set(FIELDS))
    if unknown:
        raise RecordError(f"{NAME}: unknown field {unknown[0]!r}")
    version = data.get("version")
    if isinstance(version, bool) or not isinstance(version, int) or version < 1:
        raise _fail("version", "an integer >= 1", version)
    release = data.get("release")
    if not isinstance(release, str) or not release or len(release) > 200:
        raise _fail("release", "a release name", release)
    published, expires = data.get("published"), data.get("expires")
    if parse_time(expires, "expires") <= parse_time(published, "published"):
        raise RecordError(f"{NAME}: expires ({expires}) is not after published ({published})")
    commit = _hex(data, "commit", (40, 64))
    tree = _hex(data, "tree_sha256", (64,))
    code = data.get("code")
    if code != code_path(commit):
        raise _fail("code", f"the archive of the commit, {code_path(commit)}", code)
    fleet = data.get("fleet")
    if (
        not isinstance(fleet, dict)
        or set(fleet) != {"path", "sha256"}
        or not isinstance(fleet["path"], str)
        or not fleet["path"]
        or fleet["path"].startswith("/")
        or ".." in fleet["path"].split("/")
    ):
        raise _fail("fleet", "{path: the fleet file in the tree, sha256}", fleet)
    _hex(fleet, "sha256", (64,))
    robots = data.get("robots")
    if not isinstance(robots, list) or not all(isinstance(r, str) and _ROBOT.fullmatch(r) for r in robots):
        raise _fail("robots", "a list of robot names", robots)
    if len(set(robots)) != len(robots):
        raise _fail("robots", "each robot once", sorted(r for r in robots if robots.count(r) > 1)[0])
    images = data.get("images")
    if not isinstance(images, dict):
        raise _fail("images", "robot -> {image: digest}", images)
    for robot, pins in images.items():
        if robot not in robots:
            raise _fail(f"images.{robot}", "a robot of robots", robot)
        if not isinstance(pins, dict) or not all(isinstance(k, str) and k for k in pins):
            raise _fail(f"images.{robot}", "{image reference: digest}", pins)
        for ref, digest in pins.items():
            if not isinstance(digest, str) or not _DIGEST.fullmatch(digest):
                raise _fail(f"images.{robot}.{ref}", "sha256:<64 hex digits>", digest)
    wheels = data.get("wheels")
    if not isinstance(wheels, dict):
        raise _fail("wheels", "platform -> [wheels/<file>.whl]", wheels)
    for platform, files in wheels.items():
        if not _PLATFORM.fullmatch(platform):
            raise _fail(f"wheels.{platform}", "a platform like cp313-x86_64", platform)
        if not isinstance(files, list):
            raise _fail(f"wheels.{platform}", "a list of wheel targets", files)
        for index, name in enumerate(files):
            _target_path(name, f"wheels.{platform}[{index}]", "wheels/", ".whl")
    try:
        rollout = waves.parse_plan(data.get("rollout", {}))
    except ValueError as error:
        raise RecordError(f"{NAME}: {error}") from None
    halt, reason = data.get("halt", False), data.get("halt_reason")
    if not isinstance(halt, bool):
        raise _fail("halt", "true or false", halt)
    if reason is not None and (not isinstance(reason, str) or "\n" in reason or len(reason) > 500):
        raise _fail("halt_reason", "one line of text or null", reason)
    return Record(
        version=version,
        release=release,
        published=published,
        expires=expires,
        commit=commit,
        tree_sha256=tree,
        code=code,
        fleet=dict(fleet),
        robots=tuple(robots),
        images={r: dict(p) for r, p in images.items()},
        wheels={p: list(f) for p, f in wheels.items()},
        rollout=rollout,
        halt=halt,
        halt_reason=reason,
    )
