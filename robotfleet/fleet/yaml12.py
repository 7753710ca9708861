"""YAML 1.2's core schema over PyYAML, which speaks only YAML 1.1: which tag a
plain scalar gets (only true/false are booleans, 0755 is the decimal 755,
12:30 and 2026-01-02 are text, 0x1F and 0o17 are numbers), the value of each
scalar tag, and YAML written so that it reads back the same (text YAML 1.1
or 1.2 would read as something else quoted).  Turning a document into
values, bounded, is robotfleet/fleet/loader.py's."""

from __future__ import annotations

import functools
import math
import re

import yaml
from yaml.nodes import ScalarNode

# libyaml's parser where PyYAML was built with it (its wheels are), else the
# pure-Python one: same nodes, several times slower.
LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
TAG = "tag:yaml.org,2002:"
STR, MERGE, VALUE = TAG + "str", TAG + "merge", TAG + "value"
SEQ, MAP = TAG + "seq", TAG + "map"
NULL, BOOL, INT, FLOAT = TAG + "null", TAG + "bool", TAG + "int", TAG + "float"

# The YAML 1.2 core schema's plain scalars (https://yaml.org/spec/1.2.2/#1032-tag-resolution).
CORE_SCHEMA = (
    (NULL, re.compile(r"(?:~|null|Null|NULL|)\Z")),
    (BOOL, re.compile(r"(?:true|True|TRUE|false|False|FALSE)\Z")),
    (INT, re.compile(r"(?:[-+]?[0-9]+|0o[0-7]+|0x[0-9a-fA-F]+)\Z")),
    (
        FLOAT,
        re.compile(
            r"(?:[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?"
            r"|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))\Z"
        ),
    ),
    (MERGE, re.compile(r"<<\Z")),  # merge keys: YAML 1.1's, which editors also honour
)


@functools.lru_cache(maxsize=4096)
def _plain_tag(value: str) -> str:
    """The tag of a plain scalar: a fleet file repeats a few hundred values
    (names, true, subsystems) thousands of times."""
    for tag, pattern in CORE_SCHEMA:
        if pattern.match(value):
            return tag
    return STR


@functools.lru_cache(maxsize=None)
def resolving(parser):
    """``parser`` (a PyYAML loader class) resolving plain scalars by the core schema."""

    class Yaml12(parser):
        yaml_implicit_resolvers: dict = {}

        def resolve(self, kind, value, implicit):
            if kind is ScalarNode and implicit[0]:
                return _plain_tag(value)
            return super().resolve(kind, value, implicit)

    return Yaml12


class Dumper(yaml.SafeDumper):
    """Writes fleet YAML that reads back the same under the core schema:
    text that YAML 1.1 or 1.2 would read as something else is quoted."""

    def resolve(self, kind, value, implicit):
        if kind is ScalarNode and implicit[0]:
            for tag, pattern in CORE_SCHEMA:
                if pattern.match(value):
                    return tag  # a str the emitter then quotes
        return super().resolve(kind, value, implicit)


def dump(data) -> str:
    return yaml.dump(data, Dumper=Dumper, allow_unicode=True, sort_keys=False, width=1000)


def _integer(text: str) -> int:
    if text.startswith(("0o", "0x")):
        return int(text[2:], 8 if text[1] == "o" else 16)
    return int(text, 10)


def _float(text: str) -> float:
    if text.lstrip("+-").lower() == ".inf":
        return -math.inf if text.startswith("-") else math.inf
    if text.lower() == ".nan":
        return math.nan
    return float(text)


PATTERNS = dict(CORE_SCHEMA)
SCALARS = {
    NULL: lambda text: None,
    BOOL: lambda text: text.lower() == "true",
    INT: _integer,
    FLOAT: _float,
}


def short_tag(tag: str) -> str:
    return "!!" + tag[len(TAG) :] if tag.startswith(TAG) else tag
