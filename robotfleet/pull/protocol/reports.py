"""A pull robot's report: what it last saw, what it applied, the outcome of
its last check and what runs on it, in ``refs/reports/<robot>`` of the
fleet remote (a commit holding ``report.json``).

    {"format": 1, "robot": "robot1", "time": "2026-11-25T10:00:00Z",
     "agent": "0.4.0 (tree 3f2a...)",
     "seen": {"version": 8, "release": "...", "commit": "..."},
     "applied": {"version": 7, "release": "...", "commit": "...", "time": "...Z"},
     "result": "applied" | "up-to-date" | "waiting" | "prefetched" | "halted" | "stopped" | "refused"
               | "rolled-back" | "failed",
     "reason": "one line, or null", "refusal": "tampered" (robotfleet/pull/robot/refusals.py REASONS) | null,
     "attempted": {"version": 8, "result": "rolled-back", "tries": 1} | null,
     "wave": 0, "status": {... the roles' status cells, as robotfleet status --json has them ...},
     "host_keys": ["ssh-ed25519 AAAA..."], "key": "ssh-ed25519 AAAA... (its key for the remote)",
     "enrollment": {"key": "ssh-ed25519 AAAA...", "signature": "-----BEGIN SSH SIGNATURE-----..."} | null
     (robotfleet/pull/protocol/enrollment.py: its bundle's enrollment key signs its name and keys),
     "interval": 900, "jitter": 300, "stale_after": 2, "heartbeat": 3600,
     "status_time": "...Z" (when the roles' status was read; null: never),
     "check": {"sent": 1234, "received": 5678, "requests": 2, "seconds": 0.4, "cpu": 0.3}}

Robots write these, so the operator's side reads them as untrusted input:
every field is checked, text is one line of printable characters, and a
report that cannot be read is a row saying so.  The operator reads every
report with one fetch of ``refs/reports/*``.
"""

from __future__ import annotations

import datetime
import json
import re

from robotfleet.checkers import one_line
from robotfleet.pull.protocol.enrollment import SIGNATURE
from robotfleet.pull.protocol.record import parse_time, utc

FORMAT = 1
# prefetched: waiting, with everything the release needs already in place (robotfleet/pull/robot/prefetch.py);
# halted: the release is a signed halt; stopped: its wave stopped by the failure budget.
RESULTS = ("applied", "up-to-date", "waiting", "prefetched", "halted", "stopped", "refused", "rolled-back", "failed")
FAILURES = ("rolled-back", "failed")
MAX_BYTES = 256 * 1024
# Arrays and objects within each other: a report has a few; json.loads would recurse into each.
MAX_DEPTH = 64
_NESTING = re.compile(rb'[][{}"\\]')
_KEY = re.compile(r"(ssh-ed25519|ssh-rsa|ecdsa-sha2-nistp(256|384|521)) [A-Za-z0-9+/]+={0,3}")


class ReportError(ValueError):
    """A report that cannot be read (one line)."""


def version_of(record) -> dict:
    return {"version": record.version, "release": record.release, "commit": record.commit}


def build(
    robot: str,
    now: datetime.datetime,
    result: str,
    *,
    reason: str | None = None,
    refusal: str | None = None,
    seen: dict | None = None,
    applied: dict | None = None,
    attempted: dict | None = None,
    wave: int | None = None,
    status: dict | None = None,
    host_keys=(),
    key: str | None = None,
    config=None,
    check: dict | None = None,
    agent: str | None = None,
    status_time: str | None = None,
    enrollment: dict | None = None,
) -> dict:
    if result not in RESULTS:
        raise ValueError(f"unknown result {result!r}")
    return {
        "format": FORMAT,
        "robot": robot,
        "time": utc(now),
        "agent": agent,
        "seen": seen,
        "applied": applied,
        "result": result,
        "reason": one_line(reason) if reason else None,
        "refusal": refusal,
        "attempted": attempted,
        "wave": wave,
        "status": status or {},
        "host_keys": list(host_keys),
        "key": key,
        "interval": getattr(config, "interval", None),
        "jitter": getattr(config, "jitter", None),
        "stale_after": getattr(config, "stale_after", None),
        "heartbeat": getattr(config, "heartbeat", None),
        "status_time": status_time,
        "check": check or {},
        "enrollment": enrollment,
    }


def to_bytes(report: dict) -> bytes:
    return (json.dumps(report, sort_keys=True, indent=1) + "\n").encode()


def substance(report: dict) -> dict:
    """What a report says, without when it was made, when the status was
    read or what the check cost: a robot pushes again when this changes (or
    its heartbeat is due)."""
    return {k: v for k, v in report.items() if k not in ("time", "check", "status_time")}


# -- reading (the operator's side) --------------------------------------------


def _text(value, where: str, optional: bool = True, limit: int = 500) -> str | None:
    if value is None and optional:
        return None
    if not isinstance(value, str):
        raise ReportError(f"{where}: expected text")
    return one_line(value)[:limit]


def _int(value, where: str, optional: bool = True) -> int | None:
    if value is None and optional:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ReportError(f"{where}: expected a whole number")
    return value


def _version(value, where: str) -> dict | None:
    if value is None:
        return None
    if not isinstance(value, dict):
        raise ReportError(f"{where}: expected an object")
    found = {
        "version": _int(value.get("version"), f"{where}.version", optional=False),
        "release": _text(value.get("release"), f"{where}.release"),
        "commit": _text(value.get("commit"), f"{where}.commit", limit=64),
    }
    if "time" in value:
        found["time"] = _text(value.get("time"), f"{where}.time", limit=40)
    return found


def _cells(value) -> dict:
    """The roles' status cells, made printable (any JSON shape, bounded)."""
    if not isinstance(value, dict):
        return {}

    def clean(item, depth=0):
        if depth > 6:
            return None
        if isinstance(item, str):
            return one_line(item)[:500]
        if isinstance(item, bool) or item is None or isinstance(item, (int, float)):
            return item
        if isinstance(item, list):
            return [clean(i, depth + 1) for i in item[:100]]
        if isinstance(item, dict):
            return {one_line(str(k))[:100]: clean(v, depth + 1) for k, v in list(item.items())[:100]}
        return None

    return clean(value)


def parse(data: bytes, ref_robot: str) -> dict:
    """A report as pushed to refs/reports/<ref_robot>; ReportError if it cannot be used."""
    if len(data) > MAX_BYTES:
        raise ReportError(f"report of {ref_robot}: larger than {MAX_BYTES} bytes")
    if too_deep(data, MAX_DEPTH):
        raise ReportError(f"report of {ref_robot}: nested deeper than {MAX_DEPTH} levels")
    try:
        raw = json.loads(data)
    except (ValueError, RecursionError):
        raise ReportError(f"report of {ref_robot}: not JSON") from None
    if not isinstance(raw, dict) or raw.get("format") != FORMAT:
        raise ReportError(f"report of {ref_robot}: not a format {FORMAT} report")
    if raw.get("robot") != ref_robot:
        raise ReportError(f"report of {ref_robot}: names another robot ({one_line(str(raw.get('robot')))[:60]})")
    if raw.get("result") not in RESULTS:
        raise ReportError(f"report of {ref_robot}: unknown result {one_line(str(raw.get('result')))[:40]}")
    try:
        time = parse_time(raw.get("time"), "time")
    except ValueError:
        raise ReportError(f"report of {ref_robot}: time is not a UTC time") from None
    keys = raw.get("host_keys") or []
    if not isinstance(keys, list) or not all(isinstance(k, str) and _KEY.fullmatch(k) for k in keys):
        raise ReportError(f"report of {ref_robot}: host_keys: expected public key lines")
    key = raw.get("key")
    if key is not None and not (isinstance(key, str) and _KEY.fullmatch(key)):
        raise ReportError(f"report of {ref_robot}: key: expected a public key line")
    proof = raw.get("enrollment")
    if proof is not None and not (
        isinstance(proof, dict)
        and isinstance(proof.get("key"), str)
        and _KEY.fullmatch(proof["key"])
        and isinstance(proof.get("signature"), str)
        and SIGNATURE.fullmatch(proof["signature"])
    ):
        raise ReportError(
            f"report of {ref_robot}: enrollment: expected {{key, signature}} (a public key line, an SSH signature)"
        )
    attempted = raw.get("attempted")
    if attempted is not None:
        if not isinstance(attempted, dict) or attempted.get("result") not in RESULTS:
            raise ReportError(f"report of {ref_robot}: attempted: expected {{version, result, tries}}")
        attempted = {
            "version": _int(attempted.get("version"), "attempted.version", optional=False),
            "result": attempted["result"],
            "tries": _int(attempted.get("tries"), "attempted.tries"),
        }
    check = raw.get("check") if isinstance(raw.get("check"), dict) else {}
    return {
        "format": FORMAT,
        "robot": ref_robot,
        "time": utc(time),
        "agent": _text(raw.get("agent"), "agent", limit=120),
        "seen": _version(raw.get("seen"), "seen"),
        "applied": _version(raw.get("applied"), "applied"),
        "result": raw["result"],
        "reason": _text(raw.get("reason"), "reason"),
        "refusal": _text(raw.get("refusal"), "refusal", limit=40),
        "attempted": attempted,
        "wave": _int(raw.get("wave"), "wave"),
        "status": _cells(raw.get("status")),
        "host_keys": keys,
        "key": key,
        "enrollment": proof and {"key": proof["key"], "signature": proof["signature"]},
        "interval": _int(raw.get("interval"), "interval"),
        "jitter": _int(raw.get("jitter"), "jitter"),
        "stale_after": _int(raw.get("stale_after"), "stale_after"),
        "heartbeat": _int(raw.get("heartbeat"), "heartbeat"),
        "status_time": _text(raw.get("status_time"), "status_time", limit=40),
        "check": {
            k: check[k]
            for k in ("sent", "received", "requests", "seconds", "cpu")
            if isinstance(check.get(k), (int, float)) and not isinstance(check.get(k), bool)
        },
    }


def too_deep(data: bytes, limit: int) -> bool:
    """Whether JSON ``data`` has arrays and objects more than ``limit`` deep
    (brackets in strings do not count); linear, and only counted when there
    are more than ``limit`` opening brackets at all."""
    if data.count(b"[") + data.count(b"{") <= limit:
        return False
    depth, in_string, escaped = 0, False, -1
    for match in _NESTING.finditer(data):
        at, char = match.start(), data[match.start()]
        if at == escaped:
            continue
        if in_string:
            if char == ord("\\"):
                escaped = at + 1
            elif char == ord('"'):
                in_string = False
        elif char == ord('"'):
            in_string = True
        elif char in b"[{":
            depth += 1
            if depth > limit:
                return True
        elif char in b"]}":
            depth -= 1
    return False


def stale_limit(interval: int, jitter: int, stale_after: int, heartbeat: int) -> int:
    """Seconds after which a report is stale: ``stale_after`` heartbeats,
    each with an interval and its jitter (a robot with nothing new pushes at
    its first check after its heartbeat, so pushes can be that far apart)."""
    return stale_after * (heartbeat + interval + jitter)


def stale(
    report: dict, now: datetime.datetime, interval: int, jitter: int, stale_after: int, heartbeat: int = 0
) -> bool:
    """Older than the stale limit: the robot has missed checks, or cannot report."""
    age = (now - parse_time(report["time"], "time")).total_seconds()
    return age > stale_limit(interval, jitter, stale_after, heartbeat)


def failed_for(report: dict, version: int) -> bool:
    """Whether ``report`` says its robot failed release ``version``."""
    attempted = report.get("attempted") or {}
    return attempted.get("version") == version and attempted.get("result") in FAILURES
