"""Some of pyinfra's per-operation and per-host steps, same answers, less work.

Profiling a converged rerun of ten robots (tests/bench/PROFILE.md) found a
third of the operator's CPU in a pyinfra function called for every
operation of every host, recomputing what cannot change:

- ``get_operation_order_from_stack`` (the CLI orders operations by the line
  numbers of their call stack) takes ``inspect.stack()``, which reads a line
  of source for every frame, and ``getframeinfo`` twice more per frame,
  though only each frame's file name and line number are used.
  ``getframeinfo(frame, context=0)`` gives the same file name and line
  number without reading any source; both follow from the frame's code and
  the instruction it is at, so each place is looked up once.

More are per host, found at a thousand hosts (tests/bench/SCALE.md):

- ``get_all_connectors`` reads every installed package's entry points on
  each call, and the inventory calls it for each host named
  ``@connector/...`` (every host of ours): the entry points are read once.
- ``pop_global_arguments`` looks each of its ~40 operation arguments up in
  the host's data one by one, for every operation of every host, most of
  them absent from every layer: the layers are read once for all of them
  (and ``all_global_arguments``, which evaluates ``typing.get_type_hints``
  of a TypedDict, asked once).

One more per operation of every host: ``_wrap_operation`` checks an
operation's arguments with ``inspect.signature(func).bind(...)``, building
the function's Signature anew each time (~6 % of a 1,000-host no-op); a
function's signature is fixed once it is defined, so each is made once.

``install()`` puts each in place of pyinfra's where pyinfra looks it up
when it calls it (SPEEDUPS' sites), only where what it was written from is
still the same source (its digest, pinned in robotfleet/pyinfra_private.py):
a pyinfra release that changes one keeps its own, slower but right, and one
line says so.  tests/unit/test_pyinfra_patches.py checks they answer as pyinfra's
own do, and are active with the pyinfra this project installs; what each
saves: tests/bench/patches.py, and docs/explanations/pyinfra-upstream.md
(each as a change pyinfra could take).
"""

from __future__ import annotations

import copy
import functools
import importlib
import sys
from dataclasses import dataclass
from inspect import getframeinfo

import pyinfra
from pyinfra import logger
from pyinfra.api import util as pyinfra_util
from pyinfra.api.exceptions import ArgumentTypeError

from robotfleet import pyinfra_private


@dataclass(frozen=True)
class Speedup:
    sites: tuple[str, ...]  # "module:attribute[.attribute]": where pyinfra looks it up when it calls it
    written_from: tuple[str, ...]  # the pyinfra sources it repeats or relies on (pinned in pyinfra_private)


SPEEDUPS = {
    "order": Speedup(
        ("pyinfra.api.operation:get_operation_order_from_stack",),
        ("pyinfra.api.operation:get_operation_order_from_stack",),
    ),
    # importlib's entry_points, as get_all_connectors calls it: the caller is what it was written for.
    "connectors": Speedup(("pyinfra.api.connectors:entry_points",), ("pyinfra.api.connectors:get_all_connectors",)),
    # Imported by name where it is called; its lookups are HostData.__getattr__'s.
    "pop_arguments": Speedup(
        tuple(f"pyinfra.api.{module}:pop_global_arguments" for module in ("operation", "deploy", "facts")),
        ("pyinfra.api.arguments:pop_global_arguments", "pyinfra.api.host:HostData.__getattr__"),
    ),
    # inspect's signature, as _wrap_operation calls it: the caller is what it was written for.
    "signature": Speedup(("pyinfra.api.operation:signature",), ("pyinfra.api.operation:_wrap_operation",)),
}
# pyinfra's own object at each site and each source, as imported (before any install).
_ORIGINAL = {
    path: pyinfra_private.resolve(path)
    for speedup in SPEEDUPS.values()
    for path in speedup.sites + speedup.written_from
}
COPIED_FROM = {path: pyinfra_private.pinned(path) for speedup in SPEEDUPS.values() for path in speedup.written_from}

digest = pyinfra_private.digest
arguments = importlib.import_module("pyinfra.api.arguments")


def original(key: str):
    """pyinfra's own function that speedup ``key`` replaces."""
    return _ORIGINAL[SPEEDUPS[key].sites[0]]


def operation_order_from_stack(state) -> list:
    """pyinfra.api.util.get_operation_order_from_stack, without reading source."""
    # Outermost frame first, as pyinfra's reversed(stack()); its own frame is
    # the innermost there, and so is this function's here (both skipped as
    # pyinfra's install directory, or not, alike: see the test).
    frames = []
    frame = sys._getframe(0)
    while frame is not None:
        frames.append(frame)
        frame = frame.f_back
    frames.reverse()
    places = [_place(frame) for frame in frames]
    i = 0
    if state.current_deploy_filename:  # from its frame on; not found: the last, where pyinfra's loop ends
        i = next(
            (n for n, (filename, _) in enumerate(places) if filename == state.current_deploy_filename), len(places) - 1
        )
    line_numbers = []
    if pyinfra.is_cli:
        line_numbers.append(state.current_op_file_number)
    for filename, lineno in places[i:]:
        if filename.startswith(pyinfra_util.PYINFRA_INSTALL_DIR) or filename == __file__:
            continue
        line_numbers.append(lineno)
    return line_numbers


_PLACES: dict = {}


def _place(frame) -> tuple[str, int]:
    """(file name, line number) as ``getframeinfo`` gives them."""
    key = (frame.f_code, frame.f_lasti)
    place = _PLACES.get(key)
    if place is None:
        info = getframeinfo(frame, context=0)
        place = _PLACES[key] = (info.filename, info.lineno)
    return place


@functools.lru_cache(maxsize=1)
def _global_arguments() -> tuple:
    return tuple(arguments.all_global_arguments())


@functools.lru_cache(maxsize=None)
def entry_points(group: str):
    """The installed packages' entry points of ``group``, read once."""
    return original("connectors")(group=group)


@functools.lru_cache(maxsize=None)
def signature(func):
    """inspect.signature of an operation's function, made once."""
    return original("signature")(func)


def _host_arguments(host, keys: frozenset) -> dict:
    """key -> what ``getattr(host.data, key)`` finds (uncopied), for the
    ``keys`` some layer of the host's data holds: the first layer holding
    it, as HostData.__getattr__ looks."""
    found: dict = {}
    for data in host.data.datas:
        if callable(data):
            data = data()
        if type(data) is dict:
            for key in keys.intersection(data):
                found.setdefault(key, data[key])
            continue
        for key in keys.difference(found):  # a mapping of its own: asked as pyinfra asks it
            try:
                found[key] = data[key]
            except KeyError:
                pass
    return found


@functools.lru_cache(maxsize=1)
def _argument_keys() -> frozenset:
    return frozenset(key for key, _ in _global_arguments())


def pop_global_arguments(state, host, kwargs):
    """pyinfra.api.arguments.pop_global_arguments, with the host's data
    read once for all the arguments."""
    config = state.config
    if arguments.ctx_config.isset():
        config = arguments.ctx_config.get()
        assert config is not None
    meta_kwargs = host.current_deploy_kwargs or {}
    host_values = _host_arguments(host, _argument_keys())
    result: dict = {}
    found_keys: list = []
    for key, type_ in _global_arguments():
        argument_meta = arguments.all_argument_meta[key]
        handler = argument_meta.handler
        default = argument_meta.default(config)
        if key in host_values:
            default = copy.copy(host_values[key])
        if key in kwargs:
            found_keys.append(key)
            value = kwargs.pop(key)
        else:
            value = meta_kwargs.get(key, default)
        if handler:
            value = handler(config, value)
        if value != default:
            arguments.raise_if_bad_type(value, type_, ArgumentTypeError, f"Invalid argument `{key}`:")
        result[key] = value
    return result, found_keys


OURS = {
    "order": operation_order_from_stack,
    "connectors": entry_points,
    "pop_arguments": pop_global_arguments,
    "signature": signature,
}


def _owner(site: str):
    """(the object holding the site's attribute, the attribute's name)."""
    holder, _, name = site.rpartition(".") if "." in site.partition(":")[2] else site.rpartition(":")
    return pyinfra_private.resolve(holder), name


def _changed(key: str) -> str | None:
    """The first source speedup ``key`` was written from that pyinfra has
    changed: at a site, what is bound there now (unless it is ours); else
    pyinfra's own as imported (a site another speedup may have replaced)."""
    speedup = SPEEDUPS[key]
    for path in speedup.written_from:
        if path in speedup.sites:
            owner, name = _owner(path)
            current = getattr(owner, name)
            if current is OURS[key]:
                continue
        else:
            current = _ORIGINAL[path]
        if digest(current) != COPIED_FROM[path]:
            return path
    for site in speedup.sites:
        owner, name = _owner(site)
        current = getattr(owner, name)
        if site not in speedup.written_from and current is not OURS[key] and current is not _ORIGINAL[site]:
            return site  # another function bound where pyinfra calls it
    return None


def install() -> list[str]:
    """Replace what is still as it was copied; returns what is in place."""
    replaced = []
    for key, speedup in SPEEDUPS.items():
        changed = _changed(key)
        if changed:
            module, _, name = changed.partition(":")
            logger.warning(
                f"robotfleet: pyinfra {pyinfra.__version__} has another {module}.{name} than "
                "robotfleet/pyinfra_patches.py was written from; pyinfra's own runs (slower, same answers)"
            )
            continue
        for site in speedup.sites:
            owner, name = _owner(site)
            setattr(owner, name, OURS[key])
        replaced.append(key)
    return replaced
