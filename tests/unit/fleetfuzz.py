"""Random and mutated fleet documents, from stdlib `random` with fixed seeds
(a failure replays), and what the fleet check makes of each: the unit
test (tests/unit/test_fleet_fuzz.py), the schema's (test_fleet_schema.py)
and pyinfra's own CLI on them (tests/integration/test_fleet_fuzz.py)."""

from __future__ import annotations

import random
import re
import signal
from contextlib import contextmanager

from robotfleet.fleet import yaml12
from tests.unit import harness as fleet

SHOWN = "f.yaml"
# A problem line: the file, then a YAML position, "no hosts", the document's
# shape, or a host/section and field.
_QUOTED = r"'(?:[^'\\]|\\.)*'" + "|" + r'"(?:[^"\\]|\\.)*"'
FIELD = rf"(?:[^\s'\"]|{_QUOTED})+"
SHAPE = r"expected a mapping with all/robots/laptops at the top, got \S.*"
PROBLEM = re.compile(rf"{re.escape(SHOWN)}: (line \d+: YAML error: \S.*|no hosts: \S.*|{SHAPE}|{FIELD}: \S.*)")
DOCUMENTS = 400
HANG_SECONDS = 5  # a guard against hangs, not a timing target (tests/bench/validation.py measures)

HOSTILE_TEXT = [
    "",
    " ",
    "a b",
    "$(touch /tmp/x)",
    "`id`",
    "a;b",
    "a|b",
    "a&b",
    "'",
    '"',
    "\n",
    "a\nb",
    "\t",
    "..",
    "../..",
    "/tmp",
    "/var/tmp/x",
    "${X:?}",
    "s3cr$et",
    "\u0430dmin",
    "r\u043ebot",
    "\uff11",
    "\u202e",
    "\x00",
    "\x85",
    "NO",
    "no",
    "yes",
    "on",
    "off",
    "1.10",
    "0755",
    "12:30",
    "~",
    "null",
    "2026-01-02",
    "0x1F",
    ".inf",
    "-.nan",
    "<<",
    "&a",
    "*a",
    "!tag",
    "%",
    "{",
    "}",
    "[",
    "]",
    ",",
    "#",
    "- x",
    "? x",
    "x" * 300,
]


def random_scalar(rng: random.Random):
    kind = rng.randrange(6)
    if kind == 0:
        return rng.choice([0, 1, -1, 22, 65536, 2**70, 493])
    if kind == 1:
        return rng.choice([0.5, 1.1, float("inf"), -0.0])
    if kind == 2:
        return rng.choice([True, False, None])
    if kind == 3:
        return "".join(rng.choice("abz09._-/:@+$`;|&'\" \n\t\u00e9\u0430") for _ in range(rng.randrange(12)))
    return rng.choice(HOSTILE_TEXT)


def random_value(rng: random.Random, depth: int = 0):
    kind = rng.randrange(10 if depth < 4 else 6)
    if kind < 6:
        return random_scalar(rng)
    if kind < 8:
        return [random_value(rng, depth + 1) for _ in range(rng.randrange(4))]
    keys = [random_key(rng) for _ in range(rng.randrange(4))]
    return {key: random_value(rng, depth + 1) for key in keys}


def random_key(rng: random.Random):
    kind = rng.randrange(8)
    if kind < 4:
        return rng.choice(list(fleet.setting_checks()) + ["address", "name", "serial", "subsystem", "live-restore"])
    if kind < 7:
        return random_scalar(rng) if rng.random() < 0.5 else rng.choice(HOSTILE_TEXT)
    return rng.choice([1, 8, True, None, 1.5])


def good_fleet(port: int) -> dict:
    sensor = {"name": "cam", "subsystem": "video4linux", "vendor_id": "046d", "product_id": "0825", "usb_port": "1-1"}
    return {
        "all": {"vars": {"payload_image": "reg.example.com/p:1", "ssh_port": port, "ssh_connect_retries": 0}},
        "robots": {"hosts": {f"r{i}": {"address": "127.0.0.1", "udev_sensors": [dict(sensor)]} for i in range(3)}},
        "laptops": {"hosts": {"l1": {"address": "127.0.0.1", "x11_user": "alice"}}},
    }


def mutate_data(rng: random.Random, doc: dict) -> None:
    """Wrong types at settings, random keys, hostile values, at every level."""
    for _ in range(rng.randrange(1, 4)):
        layer = rng.choice(
            [
                doc["all"]["vars"],
                doc["robots"]["hosts"]["r0"],
                doc["robots"]["hosts"]["r1"]["udev_sensors"][0],
                doc["laptops"]["hosts"]["l1"],
                doc["robots"],
            ]
        )
        key = rng.choice(list(fleet.setting_checks())) if rng.random() < 0.7 else random_key(rng)
        layer[key] = random_value(rng)
    if rng.random() < 0.2:
        doc["robots"]["hosts"][random_key(rng)] = random_value(rng)
    if rng.random() < 0.1:
        doc[random_key(rng)] = random_value(rng)


def bomb(depth: int) -> str:
    lines = ["x-l0: &l0 [lol, lol, lol, lol, lol, lol, lol, lol, lol]"]
    lines += [f"x-l{i}: &l{i} [{', '.join([f'*l{i - 1}'] * 9)}]" for i in range(1, depth)]
    return "\n".join(lines) + "\n"


def mutate_text(rng: random.Random, text: str) -> bytes:
    """Syntax-level damage: aliases and bombs, deep nesting, stray YAML
    characters, broken indentation, non-UTF-8 bytes."""
    lines = text.splitlines()
    for _ in range(rng.randrange(1, 4)):
        index = rng.randrange(len(lines))
        kind = rng.randrange(9)
        if kind == 0:
            lines[index] = lines[index].replace(":", "", 1)
        elif kind == 1:
            lines.insert(index, " " * rng.randrange(8) + rng.choice(HOSTILE_TEXT).replace("\n", ""))
        elif kind == 2:
            del lines[index]
        elif kind == 3:
            lines[index] = " " * rng.randrange(1, 3) + lines[index]
        elif kind == 4:
            lines = bomb(rng.randrange(2, 10)).splitlines() + lines
            lines.append(f"    docker_daemon_options: {{features: {{a: *l{rng.randrange(1, 2)}}}}}")
        elif kind == 5:
            deep = rng.choice([10, 60, 3000])
            lines.append(f"    payload_environment: {{A: {'[' * deep}{']' * deep}}}")
        elif kind == 6:
            cut = rng.randrange(len(lines[index]) + 1)
            lines[index] = (
                lines[index][:cut]
                + rng.choice(["&a ", "*a", "<<: *a", "!!set ", "'", '"', "{", "\t"])
                + lines[index][cut:]
            )
        elif kind == 7:
            lines[index] = lines[index] + "  # " + rng.choice(HOSTILE_TEXT).replace("\n", "")
        else:
            lines[index] = lines[index].replace("robots", "robots\u00a0", 1)
    data = ("\n".join(lines) + "\n").encode("utf-8", "surrogatepass")
    if rng.random() < 0.15:
        cut = rng.randrange(len(data) + 1)
        data = data[:cut] + bytes([rng.choice([0x80, 0xC3, 0xFF, 0xFE, 0x00, 0x1B])]) + data[cut:]
    return data


def documents(port: int, count: int, seed: int):
    rng = random.Random(seed)
    for number in range(count):
        doc = good_fleet(port)
        if rng.random() < 0.8:
            mutate_data(rng, doc)
        text = yaml12.dump(doc)
        data = mutate_text(rng, text) if rng.random() < 0.5 else text.encode()
        if rng.random() < 0.03:
            data = bytes(rng.randrange(256) for _ in range(rng.randrange(64)))
        yield f"seed {seed} document {number}", data


@contextmanager
def hang_guard(seconds: int):
    def timeout(signum, frame):
        raise TimeoutError(f"validation took more than {seconds} s")

    previous = signal.signal(signal.SIGALRM, timeout)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def outcome(data: bytes) -> list[str] | None:
    """None if accepted, else the problem lines; anything else fails the test."""
    try:
        with hang_guard(HANG_SECONDS):
            fleet.parse(data, SHOWN)
    except fleet.FleetError as error:
        return error.lines
    return None


def assert_problem_lines(lines: list[str], label: str, data: bytes):
    assert lines, f"{label}: refused without a line\n{data!r}"
    for line in lines:
        assert PROBLEM.fullmatch(line), f"{label}: not a problem line: {line!r}\n{data!r}"
