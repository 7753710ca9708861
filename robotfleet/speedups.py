"""Two of pyinfra's per-operation steps, same answers, less work.

Profiling a converged rerun of ten robots (tests/bench/PROFILE.md) found a
third of the operator's CPU in two pyinfra functions called for every
operation of every host, both recomputing what cannot change:

- ``get_operation_order_from_stack`` (the CLI orders operations by the line
  numbers of their call stack) takes ``inspect.stack()``, which reads a line
  of source for every frame, and ``getframeinfo`` twice more per frame,
  though only each frame's file name and line number are used.
  ``getframeinfo(frame, context=0)`` gives the same file name and line
  number without reading any source; both follow from the frame's code and
  the instruction it is at, so each place is looked up once.
- ``all_global_arguments`` evaluates ``typing.get_type_hints`` of a
  TypedDict on each call; the answer is fixed once pyinfra is imported.

Two more are per host, found at a thousand hosts (tests/bench/SCALE.md):

- ``get_all_connectors`` (pyinfra.api.connectors) reads every installed
  package's entry points on each call, and the inventory calls it for each
  host named ``@connector/...`` (every host of ours): the entry points are
  read once.
- ``Inventory.get_groups_data`` merges the host's groups' data on every
  lookup of host data that the host itself does not set (pyinfra looks up
  each of its ~40 operation arguments so, for every operation of every
  host): each list of groups is merged once.
- ``pop_global_arguments`` looks each of those ~40 arguments up in the
  host's data one by one, most of them absent from every layer: the
  layers are read once for all the arguments.
- ``HostData.__getattr__`` (every ``host.data.<setting>``) walks the layers
  through a generator and an exception per layer without the key: plain
  dicts are asked with ``in``.

``install()`` puts them in place of pyinfra's, each only where pyinfra's
function is still the one it was written from (its source's digest, in
COPIED_FROM): a pyinfra release that changes either keeps its own, slower
but right.  tests/unit/test_speedups.py checks they answer as pyinfra's own
do.
"""

from __future__ import annotations

import copy
import functools
import hashlib
import importlib
import inspect
import sys
from inspect import getframeinfo

import pyinfra
from pyinfra.api import arguments
from pyinfra.api import connectors as pyinfra_connectors
from pyinfra.api import util as pyinfra_util
from pyinfra.api.exceptions import ArgumentTypeError
from pyinfra.api.host import HostData
from pyinfra.api.inventory import Inventory
from pyinfra.context import ctx_config

# The module (pyinfra.api exports the decorator under the same name).
operation = importlib.import_module("pyinfra.api.operation")

_ORIGINAL = {
    "order": pyinfra_util.get_operation_order_from_stack,
    "arguments": arguments.all_global_arguments,
    "connectors": pyinfra_connectors.get_all_connectors,
    "groups_data": Inventory.get_groups_data,
    "pop_arguments": arguments.pop_global_arguments,
    "host_data": HostData.__getattr__,
}
# Where pyinfra imported pop_global_arguments by name.
_POP_USERS = [importlib.import_module(f"pyinfra.api.{name}") for name in ("operation", "deploy", "facts")]
_ENTRY_POINTS = pyinfra_connectors.entry_points
# The digest of each pyinfra function's source these were written from (pyinfra 3.10).
COPIED_FROM = {"order": "f4807f61585570e0", "arguments": "f7afbc472d78c5d2",
               "connectors": "7d05cb4b81d92078", "groups_data": "6d7b0baffe2d4773",
               "pop_arguments": "a12a311539ff5068", "host_data": "87152f64f2a65e53"}


def digest(function) -> str:
    try:
        source = inspect.getsource(function)
    except (OSError, TypeError):
        return ""
    return hashlib.sha256(source.encode()).hexdigest()[:16]


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
    if state.current_deploy_filename:
        for i, (filename, _) in enumerate(places):
            if filename == state.current_deploy_filename:
                break
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
    return tuple(_ORIGINAL["arguments"]())


def all_global_arguments() -> list:
    """pyinfra.api.arguments.all_global_arguments, evaluated once."""
    return list(_global_arguments())


@functools.lru_cache(maxsize=None)
def entry_points(group: str):
    """The installed packages' entry points of ``group``, read once."""
    return _ENTRY_POINTS(group=group)


def groups_data(inventory, groups) -> dict:
    """Inventory.get_groups_data, merged once for each list of groups (the
    inventory's group data is set when it is made, before any lookup)."""
    memo = inventory.__dict__.setdefault("_merged_groups_data", {})
    key = tuple(groups)
    if key not in memo:
        memo[key] = _ORIGINAL["groups_data"](inventory, groups)
    return memo[key]


def _host_arguments(host, keys) -> dict:
    """key -> what ``getattr(host.data, key)`` finds, for the ``keys`` some
    layer of the host's data holds: the first layer holding it, as
    HostData.__getattr__ looks (uncopied)."""
    found: dict = {}
    for data in host.data.datas:
        if callable(data):
            data = data()
        for key in keys.intersection(data):
            found.setdefault(key, data[key])
    return found


@functools.lru_cache(maxsize=1)
def _argument_keys() -> frozenset:
    return frozenset(key for key, _ in _global_arguments())


def pop_global_arguments(state, host, kwargs):
    """pyinfra.api.arguments.pop_global_arguments, with the host's data
    read once for all the arguments."""
    config = state.config
    if ctx_config.isset():
        config = ctx_config.get()
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
            pyinfra_util.raise_if_bad_type(value, type_, ArgumentTypeError, f"Invalid argument `{key}`:")
        result[key] = value
    return result, found_keys


def host_data_getattr(self, key: str):
    """HostData.__getattr__: the first layer holding ``key``, copied."""
    for data in self.datas:
        if callable(data):
            data = data()
        if type(data) is dict:
            if key in data:
                return copy.copy(data[key])
            continue
        try:
            return copy.copy(data[key])
        except KeyError:
            pass
    raise AttributeError(f"Host `{self.host}` has no data `{key}`")


def install() -> list[str]:
    """Replace what is still as it was copied; returns what was replaced."""
    replaced = []
    if digest(_ORIGINAL["order"]) == COPIED_FROM["order"]:
        operation.get_operation_order_from_stack = operation_order_from_stack
        replaced.append("order")
    if digest(_ORIGINAL["arguments"]) == COPIED_FROM["arguments"]:
        arguments.all_global_arguments = all_global_arguments
        replaced.append("arguments")
    if digest(_ORIGINAL["connectors"]) == COPIED_FROM["connectors"]:
        pyinfra_connectors.entry_points = entry_points
        replaced.append("connectors")
    if digest(_ORIGINAL["groups_data"]) == COPIED_FROM["groups_data"]:
        Inventory.get_groups_data = groups_data
        replaced.append("groups_data")
    if all(digest(_ORIGINAL[name]) == COPIED_FROM[name] for name in ("pop_arguments", "host_data")):
        for module in _POP_USERS:
            module.pop_global_arguments = pop_global_arguments
        replaced.append("pop_arguments")
    if digest(_ORIGINAL["host_data"]) == COPIED_FROM["host_data"]:
        HostData.__getattr__ = host_data_getattr
        replaced.append("host_data")
    return replaced
