"""What a robot trusts, kept between checks (robotfleet/pull/robot/verify.py
says how it moves):

    <state>/trust.json      {"format": 1, "time": "...Z", "version": N, "release": "..."}

``time`` is the last trusted time and ``version`` the highest record
accepted.  Until issue 53 a check that read what the last verification
read was that verification again, without TUF (verified.json and
verified.release.json beside it; the agent removes them): every check now
verifies in full.
"""

from __future__ import annotations

import datetime
import json
from dataclasses import dataclass
from pathlib import Path

from robotfleet import atomicfile
from robotfleet.pull.protocol import record as records

STATE_FORMAT = 1
EPOCH = datetime.datetime(1970, 1, 1, tzinfo=datetime.timezone.utc)
EARLIER = ("verified.json", "verified.release.json")  # what the recall of earlier releases kept


class Unreadable(ValueError):
    """trust.json cannot be read (one line)."""


@dataclass(frozen=True)
class State:
    """What the robot last trusted (trust.json)."""

    time: datetime.datetime = EPOCH
    version: int = 0
    release: str | None = None


def read_state(state_dir) -> State:
    """The trust state kept in ``state_dir`` (defaults if it has none yet); Unreadable."""
    try:
        raw = json.loads(Path(state_dir, "trust.json").read_text())
        return State(records.parse_time(raw["time"], "trust.json time"), int(raw["version"]), raw.get("release"))
    except FileNotFoundError:
        return State()
    except (ValueError, KeyError, TypeError) as error:
        raise Unreadable(f"{Path(state_dir, 'trust.json')}: unreadable trust state ({error})") from None


def write_atomic(path: Path, data: bytes) -> None:
    atomicfile.write(path, data)


def write_state(state_dir, state: State) -> None:
    text = {"format": STATE_FORMAT, "time": records.utc(state.time), "version": state.version, "release": state.release}
    write_atomic(Path(state_dir, "trust.json"), (json.dumps(text, sort_keys=True) + "\n").encode())
