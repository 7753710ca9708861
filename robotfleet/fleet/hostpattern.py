"""An inventory's host patterns, expanded as Ansible expands them.

``robot[01:03]`` is robot01, robot02, robot03 (a leading zero fixes the
width), ``robot[a:c]`` robota, robotb, robotc, ``robot[1:10:2]`` every
second number; a name may hold several ranges (``rack[1:2]-robot[a:b]``),
and ``robot1:2222`` gives the host its SSH port.  This is the YAML and the
INI inventories' ``ansible.plugins.inventory.expand_hostname_range``, with
its refusals as one line each; a range Ansible would silently expand to no
host (``[5:1]``) is refused here too.
"""

from __future__ import annotations

import re
import string

MAX_HOSTS = 100_000  # far more than any fleet; a typo like [0:99999999] is not a fleet
_PORT = re.compile(r"(?P<name>.+?):(?P<port>[0-9]+)")


class PatternProblem(ValueError):
    """Why a host pattern cannot be expanded, as one line."""


def expand(pattern: str) -> tuple[list[str], int | None]:
    """(host names, SSH port or None) of ``pattern``."""
    name, port = pattern, None
    match = _PORT.fullmatch(pattern)
    if match and match["name"].count("[") == match["name"].count("]"):
        name, port = match["name"], int(match["port"])
    elif pattern.endswith(":"):
        raise PatternProblem(f"host pattern {pattern!r} ends in ':' with no port after it")
    if "[" not in name and "]" not in name:
        return [name], port
    names = _ranges(name, pattern)
    return names, port


def _ranges(name: str, pattern: str) -> list[str]:
    start, end = name.find("["), name.find("]")
    if start < 0:
        if end >= 0:
            raise PatternProblem(f"host pattern {pattern!r}: ']' without '['")
        return [name]
    if end < start:
        raise PatternProblem(f"host pattern {pattern!r}: '[' is not closed by ']'")
    head, spec, tail = name[:start], name[start + 1 : end], name[end + 1 :]
    bounds = spec.split(":")
    if len(bounds) not in (2, 3):
        raise PatternProblem(f"host range [{spec}] in {pattern!r} must be [begin:end] or [begin:end:step]")
    begin, last = bounds[0] or "0", bounds[1]
    step = bounds[2] if len(bounds) == 3 else "1"
    if not last:
        raise PatternProblem(f"host range [{spec}] in {pattern!r} has no end")
    if not step.isdigit() or int(step) < 1:
        raise PatternProblem(f"host range [{spec}] in {pattern!r}: the step must be a whole number of at least 1")
    if len(begin) == 1 and len(last) == 1 and begin in string.ascii_letters and last in string.ascii_letters:
        first, final = string.ascii_letters.index(begin), string.ascii_letters.index(last)
        if first > final:
            raise PatternProblem(f"host range [{spec}] in {pattern!r} must have begin <= end")
        values = list(string.ascii_letters[first : final + 1 : int(step)])
    elif begin.isdigit() and last.isdigit():
        if begin[0] == "0" and len(begin) > 1 and len(begin) != len(last):
            raise PatternProblem(
                f"host range [{spec}] in {pattern!r}: a zero-padded begin needs an end of the "
                f"same width ({begin}:{'0' * (len(begin) - len(last))}{last})"
            )
        if int(begin) > int(last):
            raise PatternProblem(f"host range [{spec}] in {pattern!r} must have begin <= end")
        width = len(begin) if begin[0] == "0" and len(begin) > 1 else 0
        count = (int(last) - int(begin)) // int(step) + 1
        if count > MAX_HOSTS:
            raise PatternProblem(f"host range [{spec}] in {pattern!r} makes {count} hosts (at most {MAX_HOSTS})")
        values = [str(n).zfill(width) for n in range(int(begin), int(last) + 1, int(step))]
    else:
        raise PatternProblem(
            f"host range [{spec}] in {pattern!r}: begin and end must both be numbers or both single letters"
        )
    names: list[str] = []
    for value in values:
        names.extend(_ranges(head + value + tail, pattern))
        if len(names) > MAX_HOSTS:
            raise PatternProblem(f"host pattern {pattern!r} makes more than {MAX_HOSTS} hosts")
    return names
