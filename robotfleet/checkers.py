"""Small composable value checkers for fleet data.

A checker is a callable ``check(value) -> list[Problem]`` where a problem is a
``(subpath, message)`` pair; ``subpath`` is appended to the field being checked
(e.g. ``"[1].serial"``).  They are pure so validation runs before any host is
contacted and is unit-tested without hosts.
"""

from __future__ import annotations

import datetime
import difflib
import re
from collections.abc import Callable
from typing import Any

Problem = tuple[str, str]
Checker = Callable[[Any], list[Problem]]


class Misread:
    """A scalar YAML read as something other than what was written: a key
    (``010`` is the number 10, ``true`` a boolean) or a number written in a
    way YAML changes (``0755`` is 755, ``1.10`` is 1.1, ``0x1F`` is 31).
    Kept with its text so a check can say "quote it" instead of silently
    renaming a host or changing a value."""

    __slots__ = ("value", "text")

    def __init__(self, value: Any, text: str):
        self.value, self.text = value, text

    def __hash__(self):
        return hash((Misread, self.text))

    def __eq__(self, other):
        return isinstance(other, Misread) and other.text == self.text

    def __str__(self):
        return self.text

    __repr__ = __str__


MAX_SHOWN = 80


def shown(value: str) -> str:
    """repr() of a string, cut to one short line (problems are one line each)."""
    text = repr(value)
    return text if len(text) <= MAX_SHOWN else text[: MAX_SHOWN - 5] + "...'"


def describe(value: Any) -> str:
    if value is None:
        return "nothing (null)"
    if isinstance(value, bool):
        return f"a boolean ({str(value).lower()})"
    if isinstance(value, (int, float)):
        return str(value)
    if isinstance(value, str):
        return shown(value)
    if isinstance(value, list):
        return "a list"
    if isinstance(value, dict):
        return "a mapping"
    if isinstance(value, Misread):
        read = describe(value.value)
        return read if read == value.text else f"{value.text} (read by YAML as {read})"
    if isinstance(value, (datetime.date, datetime.datetime)):
        return f"a date ({value.isoformat()})"
    return getattr(value, "described", None) or type(value).__name__


def _not_text(value: Any) -> bool:
    """YAML reads some unquoted text as another type: true -> a boolean,
    1.10 -> 1.1, 0755 -> 755, 0x1F -> 31."""
    return isinstance(value, (bool, int, float, datetime.date)) or isinstance(value, Misread)


def expected_string(value: Any, what: str = "a string") -> str:
    message = f"expected {what}, got {describe(value)}"
    return message + "; quote it" if _not_text(value) else message


def with_schema(check: Checker, schema: dict) -> Checker:
    """Attach the JSON Schema of what ``check`` accepts (robotfleet/fleet/schema.py
    builds the fleet file's schema for editors from these)."""
    check.schema = schema
    return check


def json_pattern(pattern: str) -> str:
    """A fullmatch pattern as a JSON Schema (ECMA-262, search) pattern."""
    return f"^(?:{pattern})$"


def string(pattern: str | None = None, what: str = "a string", choices=None) -> Checker:
    regex = re.compile(pattern, re.ASCII) if pattern else None

    def check(value):
        if not isinstance(value, str):
            return [("", expected_string(value))]
        if choices is not None and value not in choices:
            return [("", f"expected one of {', '.join(choices)}, got {shown(value)}")]
        if regex and not regex.fullmatch(value):
            return [("", f"expected {what}, got {shown(value)}")]
        return []

    schema = {"type": "string", "description": what} if what != "a string" else {"type": "string"}
    if choices is not None:
        schema["enum"] = list(choices)
    if pattern:
        schema["pattern"] = json_pattern(pattern)
    return with_schema(check, schema)


def boolean(value):
    if not isinstance(value, bool):
        return [("", f"expected true or false, got {describe(value)}")]
    return []


boolean.schema = {"type": "boolean"}


def integer(minimum: int | None = None, maximum: int | None = None) -> Checker:
    def check(value):
        if isinstance(value, bool) or not isinstance(value, int):
            return [("", f"expected a whole number, got {describe(value)}")]
        if minimum is not None and value < minimum:
            return [("", f"expected at least {minimum}, got {value}")]
        if maximum is not None and value > maximum:
            return [("", f"expected at most {maximum}, got {value}")]
        return []

    schema = {"type": "integer"}
    if minimum is not None:
        schema["minimum"] = minimum
    if maximum is not None:
        schema["maximum"] = maximum
    return with_schema(check, schema)


def optional(inner: Checker) -> Checker:
    def check(value):
        return [] if value is None else inner(value)

    return with_schema(check, {"anyOf": [inner.schema, {"type": "null"}]})


def list_of(inner: Checker, unique: bool = False) -> Checker:
    def check(value):
        if not isinstance(value, list):
            return [("", f"expected a list, got {describe(value)}")]
        problems = []
        valid = []
        for index, item in enumerate(value):
            found = inner(item)
            problems += [(f"[{index}]{sub}", msg) for sub, msg in found]
            if not found:
                valid.append((index, item))
        if unique:
            seen = set()
            for index, item in valid:
                key = repr(item)
                if key in seen:
                    problems.append((f"[{index}]", f"duplicate entry {describe(item)}"))
                seen.add(key)
        return problems

    schema = {"type": "array", "items": inner.schema}
    if unique:
        schema["uniqueItems"] = True
    return with_schema(check, schema)


def key_name(key: Any) -> str:
    """A mapping key as shown in a field path: plain if it is a simple name."""
    if isinstance(key, str) and _PLAIN_KEY.fullmatch(key):
        return key
    return str(key) if isinstance(key, Misread) else shown(key) if isinstance(key, str) else describe(key)


_PLAIN_KEY = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.:/@+-]*", re.ASCII)


def mapping_of(key: Checker, value_check: Checker) -> Checker:
    def check(value):
        if not isinstance(value, dict):
            return [("", f"expected a mapping, got {describe(value)}")]
        problems = []
        for k, v in value.items():
            where = f".{key_name(k)}"
            found = key(k)
            problems += [(f"{where}{sub}", msg) for sub, msg in found]
            if not found:
                problems += [(f"{where}{sub}", msg) for sub, msg in value_check(v)]
        return problems

    return with_schema(
        check, {"type": "object", "propertyNames": key.schema, "additionalProperties": value_check.schema}
    )


MAX_JSON_VALUES = 10_000
MAX_JSON_DEPTH = 20


def any_json(value):
    """A JSON-representable value (daemon.json options), walked with a budget:
    aliases can make a small YAML file stand for billions of values."""
    problems: list[Problem] = []
    budget = [MAX_JSON_VALUES]

    def walk(item, where: str, depth: int) -> bool:
        budget[0] -= 1
        if budget[0] < 0:
            problems.append(("", f"more than {MAX_JSON_VALUES} values (YAML aliases expand); daemon options are small"))
            return False
        if depth > MAX_JSON_DEPTH:
            problems.append((where, f"nested more than {MAX_JSON_DEPTH} levels deep"))
            return False
        if item is None or isinstance(item, (bool, int, str)):
            return True
        if isinstance(item, float):
            if item != item or item in (float("inf"), float("-inf")):
                problems.append((where, f"expected a JSON number, got {item}"))
            return True
        if isinstance(item, list):
            return all(walk(element, f"{where}[{index}]", depth + 1) for index, element in enumerate(item))
        if isinstance(item, dict):
            for k, v in item.items():
                if not isinstance(k, str):
                    problems.append((f"{where}.{key_name(k)}", f"keys must be strings, got {describe(k)}; quote it"))
                    continue
                if not walk(v, f"{where}.{key_name(k)}", depth + 1):
                    return False
            return True
        problems.append((where, f"expected a JSON value, got {describe(item)}; quote it"))
        return True

    walk(value, "", 0)
    return problems


any_json.schema = {}


def size_problem(value, limit: int = MAX_JSON_VALUES) -> list[Problem]:
    """A problem if ``value`` holds more than ``limit`` values, counting each
    use of a YAML alias (what it would be once written out)."""
    stack, seen = [value], 0
    while stack:
        item = stack.pop()
        seen += 1
        if seen > limit:
            return [("", f"more than {limit} values (YAML aliases expand); daemon options are small")]
        if isinstance(item, dict):
            stack.extend(item.values())
        elif isinstance(item, list):
            stack.extend(item)
    return []


def text(value):
    """An environment variable value: a string (YAML would silently change
    true, 1.10 or 0755 on the way; quoted, nothing changes)."""
    if isinstance(value, str):
        if "\x00" in value:
            return [("", "NUL characters cannot be in an environment value")]
        return []
    if isinstance(value, bool):
        return [
            ("", f"expected a string, got {describe(value)}; quote it (YAML reads an unquoted true/false as a boolean)")
        ]
    if _not_text(value):
        return [("", expected_string(value))]
    return [("", f"expected a string, got {describe(value)}")]


text.schema = {
    "type": "string",
    "pattern": "^[^\\x00]*$",
    "description": "a string: quote values YAML would read as something else",
}


# Patterns shared by several settings.
USER_NAME = r"[a-z_][a-z0-9_-]{0,31}"
IDENTIFIER = r"[a-z0-9][a-z0-9_-]{0,62}"
ABS_PATH = r"/[A-Za-z0-9._/@+-]*"
ENV_NAME = r"[A-Za-z_][A-Za-z0-9_]*"
HEX4 = r"[0-9a-fA-F]{4}"


def did_you_mean(key: str, known) -> str:
    close = difflib.get_close_matches(key, list(known), n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


_CONTROL = {i: f"\\x{i:02x}" for i in [*range(0x20), 0x7F, *range(0x80, 0xA0)]}
_CONTROL.update({0x2028: "\\u2028", 0x2029: "\\u2029"})


def one_line(line: str) -> str:
    """A line with any control character (a newline in a host name, an
    escape sequence in text a host sent) escaped: one problem is one line,
    and nothing printed can move the operator's cursor."""
    return line.translate(_CONTROL)
