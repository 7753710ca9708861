"""Small composable value checkers for fleet data.

A checker is a callable ``check(value) -> list[Problem]`` where a problem is a
``(subpath, message)`` pair; ``subpath`` is appended to the field being checked
(e.g. ``"[1].serial"``).  They are pure so validation runs before any host is
contacted and is unit-tested without hosts.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from typing import Any

Problem = tuple[str, str]
Checker = Callable[[Any], list[Problem]]


def describe(value: Any) -> str:
    if value is None:
        return "nothing (null)"
    if isinstance(value, bool):
        return f"a boolean ({str(value).lower()})"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return str(value)
    if isinstance(value, str):
        return repr(value)
    if isinstance(value, list):
        return "a list"
    if isinstance(value, dict):
        return "a mapping"
    return type(value).__name__


def string(pattern: str | None = None, what: str = "a string", choices=None) -> Checker:
    regex = re.compile(pattern) if pattern else None

    def check(value):
        if not isinstance(value, str):
            return [("", f"expected a string, got {describe(value)}")]
        if choices is not None and value not in choices:
            return [("", f"expected one of {', '.join(choices)}, got {value!r}")]
        if regex and not regex.fullmatch(value):
            return [("", f"expected {what}, got {value!r}")]
        return []

    return check


def boolean(value):
    if not isinstance(value, bool):
        return [("", f"expected true or false, got {describe(value)}")]
    return []


def integer(minimum: int | None = None, maximum: int | None = None) -> Checker:
    def check(value):
        if isinstance(value, bool) or not isinstance(value, int):
            return [("", f"expected a whole number, got {describe(value)}")]
        if minimum is not None and value < minimum:
            return [("", f"expected at least {minimum}, got {value}")]
        if maximum is not None and value > maximum:
            return [("", f"expected at most {maximum}, got {value}")]
        return []

    return check


def optional(inner: Checker) -> Checker:
    def check(value):
        return [] if value is None else inner(value)

    return check


def list_of(inner: Checker, unique: bool = False) -> Checker:
    def check(value):
        if not isinstance(value, list):
            return [("", f"expected a list, got {describe(value)}")]
        problems = []
        for index, item in enumerate(value):
            problems += [(f"[{index}]{sub}", msg) for sub, msg in inner(item)]
        if unique:
            seen = set()
            for index, item in enumerate(value):
                key = repr(item)
                if key in seen:
                    problems.append((f"[{index}]", f"duplicate entry {item!r}"))
                seen.add(key)
        return problems

    return check


def mapping_of(key: Checker, value_check: Checker) -> Checker:
    def check(value):
        if not isinstance(value, dict):
            return [("", f"expected a mapping, got {describe(value)}")]
        problems = []
        for k, v in value.items():
            problems += [(f".{k}{sub}", msg) for sub, msg in key(k)]
            problems += [(f".{k}{sub}", msg) for sub, msg in value_check(v)]
        return problems

    return check


def any_json(value):
    """A JSON-representable value (daemon.json options)."""
    if value is None or isinstance(value, (bool, int, float, str)):
        return []
    if isinstance(value, list):
        return [p for item in value for p in any_json(item)]
    if isinstance(value, dict):
        problems = []
        for k, v in value.items():
            if not isinstance(k, str):
                problems.append(("", f"keys must be strings, got {describe(k)}"))
            problems += [(f".{k}{sub}", msg) for sub, msg in any_json(v)]
        return problems
    return [("", f"expected a JSON value, got {describe(value)}")]


def scalar(value):
    """An environment variable value: string, number or boolean."""
    if isinstance(value, (str, int, float, bool)):
        return []
    return [("", f"expected a string or number, got {describe(value)}")]


# Patterns shared by several settings.
USER_NAME = r"[a-z_][a-z0-9_-]{0,31}"
IDENTIFIER = r"[a-z0-9][a-z0-9_-]{0,62}"
ABS_PATH = r"/[A-Za-z0-9._/@+-]*"
ENV_NAME = r"[A-Za-z_][A-Za-z0-9_]*"
HEX4 = r"[0-9a-fA-F]{4}"
