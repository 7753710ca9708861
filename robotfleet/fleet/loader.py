"""Read fleet YAML into plain data: total, bounded, one line per problem.

The fleet file is YAML 1.2 (core schema), as editors' YAML extensions and
check-jsonschema read it (only true/false are booleans, 0755 is the decimal
755): PyYAML only speaks YAML 1.1, so the resolver (which tag a plain scalar
gets) and the scalar constructors are our own, in robotfleet/fleet/yaml12.py.

libyaml (CSafeLoader's parser) builds the node tree; this module turns nodes
into Python values itself instead of using PyYAML's constructor, because it
has to: refuse duplicate keys while still honouring merge keys (``<<``), keep
keys YAML did not read as strings (``010`` is 8) so the checks can say
"quote it", refuse recursive aliases and nesting deeper than MAX_DEPTH, and
share aliased values instead of copying them (a billion-laughs document stays
small here; the checks bound their own walks).
"""

from __future__ import annotations

import contextlib
import gc

import yaml
from yaml.nodes import MappingNode, ScalarNode, SequenceNode

from robotfleet.checkers import Misread
from robotfleet.fleet.yaml12 import LOADER, MAP, MERGE, PATTERNS, SCALARS, SEQ, STR, VALUE, resolving, short_tag

MAX_DEPTH = 50


class Vaulted:
    """An ansible-vault value (``!vault |``): kept, never decrypted, so that
    Ansible's own variables holding one (ansible_become_password) are
    ignored like the others, and a setting holding one is refused."""

    __slots__ = ("text",)
    described = "an ansible-vault value (!vault)"

    def __init__(self, text: str):
        self.text = text


def _unsupported(tag: str) -> str:
    if tag == "!unsafe":
        return "Ansible's !unsafe tag: drop it (values are not templated here)"
    return f"the YAML tag {short_tag(tag)!r} is not supported here"


class YamlProblem(Exception):
    """Why a byte string is not a fleet document we can read, as one line."""

    def __init__(self, line: int | None, message: str):
        super().__init__(f"line {line}: YAML error: {message}" if line else f"YAML error: {message}")


def load(data: bytes | str, places: dict | None = None):
    """The document's data (None for an empty document), or YamlProblem.
    ``places``, if given, gets each mapping's keys' lines: id(the mapping)
    -> {key: line} (where a value is written, for inventory --host)."""
    text = _decode(data) if isinstance(data, bytes) else data
    with _no_collection():
        return _load(text, places)


@contextlib.contextmanager
def _no_collection():
    """Python's cyclic garbage collector paused: a large fleet file makes
    hundreds of thousands of nodes and values (none in a cycle), and the
    collector's passes over them cost more than reading them (5,000 robots
    with sensors: 0.75 s instead of 0.25 s)."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


def _load(text: str, places: dict | None):
    loader = None
    try:
        loader = resolving(LOADER)(text)
        node = loader.get_single_node()
    except yaml.reader.ReaderError as error:
        raise _reader_problem(error, text) from None
    except yaml.MarkedYAMLError as error:
        raise _marked_problem(error, text) from None
    except yaml.YAMLError as error:
        raise YamlProblem(None, str(error).replace("\n", " ")) from None
    except RecursionError:  # PyYAML's own composer recurses (libyaml's does not)
        raise YamlProblem(None, f"nested more than {MAX_DEPTH} levels deep") from None
    finally:
        if loader is not None:
            loader.dispose()
    return None if node is None else _Builder(places).build(node, 0)


def _decode(data: bytes) -> str:
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as error:
        line = data.count(b"\n", 0, error.start) + 1
        raise YamlProblem(line, f"not UTF-8 text (byte 0x{data[error.start]:02x}); save the file as UTF-8") from None


def _reader_problem(error, text: str) -> YamlProblem:
    # libyaml's position counts bytes, PyYAML's own reader characters.
    encoded = text.encode("utf-8", "surrogatepass") if LOADER is not yaml.SafeLoader else text
    position = min(max(int(getattr(error, "position", 0) or 0), 0), len(encoded))
    character = getattr(error, "character", None)
    shown = f"U+{character:04X}" if isinstance(character, int) else repr(character)
    newline = b"\n" if isinstance(encoded, bytes) else "\n"
    return YamlProblem(encoded.count(newline, 0, position) + 1, f"character {shown} is not allowed in YAML")


def _marked_problem(error: yaml.MarkedYAMLError, text: str) -> YamlProblem:
    """Unclosed quotes and flow collections are reported where they were
    opened (the parser gives up far below); other errors where they are."""
    context, problem = error.context or "", error.problem or "invalid YAML"
    opened, found = error.context_mark, error.problem_mark
    if "maximum nesting depth" in problem:  # libyaml 0.2.6+ stops deep nesting itself
        return YamlProblem(
            (found or opened).line + 1 if (found or opened) else None, f"nested more than {MAX_DEPTH} levels deep"
        )
    if opened is not None and found is not None and ("quoted" in context or "flow" in context):
        return YamlProblem(
            opened.line + 1,
            f"{context.removeprefix('while scanning ').removeprefix('while parsing ')} "
            f"opened here (column {opened.column + 1})"
            f" is not closed: {problem} (line {found.line + 1}, column {found.column + 1})",
        )
    quote = _runaway_quote(text, found) if found is not None else None
    if quote is not None:
        start, end = quote
        return YamlProblem(
            start.line + 1,
            f"a quoted value opened here (column {start.column + 1}) runs on to line {end.line + 1}, where "
            f"{problem} (column {found.column + 1}); is its closing quote missing?",
        )
    primary = found or opened
    if found is not None and "cannot start any token" in problem:
        lines = text.splitlines()
        line = lines[found.line] if found.line < len(lines) else ""
        character = line[found.column] if found.column < len(line) else ""
        problem = f"found {character!r}, which cannot start any token" + (
            "; indent with spaces, not tabs" if character == "\t" else ""
        )
    if context.startswith("expected a single document"):
        problem = "a second YAML document starts here; a fleet file is one document"
    elif context and opened is not None and found is not None and opened.line != found.line:
        problem += f" ({context} from line {opened.line + 1})"
    return YamlProblem(primary.line + 1 if primary is not None else None, problem)


def _runaway_quote(text: str, found):
    """(start, end) marks of a quoted value spanning several lines that ends
    on the line of the error ``found``: a quote left open on its first line
    is closed by the next quote character, lines below, and the parser only
    gives up there."""
    loader = resolving(LOADER)(text)
    last = None
    try:
        while True:
            token = loader.get_token()
            if token is None or token.start_mark.line > found.line:
                break
            if (
                isinstance(token, yaml.ScalarToken)
                and token.style in ('"', "'")
                and token.end_mark.line > token.start_mark.line
            ):
                last = token
    except yaml.YAMLError:
        pass
    finally:
        loader.dispose()
    if last is not None and last.end_mark.line == found.line:
        return last.start_mark, last.end_mark
    return None


def _changed(number, text: str) -> bool:
    """0755 is 755, 1.10 is 1.1, 0x1F is 31: a number whose plain spelling is
    not what was written (where text was meant, the text is lost)."""
    return text != (str(number) if isinstance(number, int) else repr(number))


class _Builder:
    def __init__(self, places: dict | None = None):
        self.built: dict[int, object] = {}  # id(node) -> value: aliases share it
        self.building: set[int] = set()
        self.places = places  # id(mapping) -> {key: line}, when asked for

    def build(self, node, depth: int):
        key = id(node)
        if key in self.built:
            return self.built[key]
        if key in self.building:
            raise YamlProblem(node.start_mark.line + 1, "an alias refers to its own anchor (a recursive value)")
        if depth > MAX_DEPTH:
            raise YamlProblem(node.start_mark.line + 1, f"nested more than {MAX_DEPTH} levels deep")
        if isinstance(node, ScalarNode):
            value = self.scalar(node)
        elif isinstance(node, SequenceNode):
            self.require(node, SEQ)
            self.building.add(key)
            value = [self.value(item, depth + 1) for item in node.value]
            self.building.discard(key)
        else:
            self.require(node, MAP)
            self.building.add(key)
            value = self.mapping(node, depth)
            self.building.discard(key)
        self.built[key] = value
        return value

    def value(self, node, depth: int):
        # Plain strings are most of a fleet file: no bookkeeping for them.
        if node.tag == STR and type(node) is ScalarNode:
            return node.value
        return self.build(node, depth)

    @staticmethod
    def require(node, tag: str):
        if node.tag != tag:
            raise YamlProblem(node.start_mark.line + 1, _unsupported(node.tag))

    @staticmethod
    def scalar(node: ScalarNode):
        if node.tag in (STR, VALUE):
            return node.value
        if node.tag == "!vault":
            return Vaulted(node.value)
        convert = SCALARS.get(node.tag)
        if convert is None:
            raise YamlProblem(node.start_mark.line + 1, _unsupported(node.tag))
        try:
            if not PATTERNS[node.tag].match(node.value):  # an explicit tag: !!bool yes
                raise ValueError(node.value)
            value = convert(node.value)
        except (ValueError, TypeError, OverflowError):
            raise YamlProblem(
                node.start_mark.line + 1, f"{node.value!r} is not a valid {node.tag.rsplit(':', 1)[-1]}"
            ) from None
        if isinstance(value, (int, float)) and not isinstance(value, bool) and _changed(value, node.value):
            return Misread(value, node.value)
        return value

    def mapping(self, node: MappingNode, depth: int) -> dict:
        result: dict = {}
        merges = []
        lines: dict | None = {} if self.places is not None else None
        for key_node, value_node in node.value:
            if key_node.tag == MERGE:
                merges.append(value_node)
                continue
            key = key_node.value if key_node.tag == STR and type(key_node) is ScalarNode else self.key(key_node)
            if key in result:
                raise YamlProblem(key_node.start_mark.line + 1, f"duplicate key {str(key)!r}")
            result[key] = self.value(value_node, depth + 1)
            if lines is not None:
                lines[key] = key_node.start_mark.line + 1
        # Own keys win over merged ones; among merged mappings the first wins.
        for value_node in merges:
            sources = value_node.value if isinstance(value_node, SequenceNode) else [value_node]
            for source in sources:
                if not isinstance(source, MappingNode):
                    raise YamlProblem(
                        value_node.start_mark.line + 1, "a merge key (<<) takes a mapping or a list of mappings"
                    )
                merged = self.build(source, depth + 1)
                for merged_key, merged_value in merged.items():
                    result.setdefault(merged_key, merged_value)
                    if lines is not None:
                        lines.setdefault(merged_key, self.places.get(id(merged), {}).get(merged_key))
        if lines is not None:
            self.places[id(result)] = lines
        return result

    def key(self, node):
        if not isinstance(node, ScalarNode):
            kind = "list" if isinstance(node, SequenceNode) else "mapping"
            raise YamlProblem(node.start_mark.line + 1, f"a key must be a plain name, not a {kind}")
        if node.tag in (STR, VALUE):
            return node.value
        value = self.scalar(node)
        return value if isinstance(value, Misread) else Misread(value, node.value)
