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

``install()`` puts each in place of pyinfra's where pyinfra looks it up
when it calls it (SITES), only where the function bound there is still the
one it was written from (its source's digest, pinned in
robotfleet/pyinfra_private.py): a pyinfra release that changes either keeps
its own, slower but right, and one line says so.  tests/unit/test_speedups.py
checks they answer as pyinfra's own do, and are active with the pyinfra this
project installs.
"""

from __future__ import annotations

import functools
import importlib
import sys
from inspect import getframeinfo

import pyinfra
from pyinfra import logger
from pyinfra.api import util as pyinfra_util

from robotfleet import pyinfra_private

# Where pyinfra looks each function up when it calls it: the object checked
# is the object replaced.
SITES = {
    "order": ("pyinfra.api.operation", "get_operation_order_from_stack"),
    "arguments": ("pyinfra.api.arguments", "all_global_arguments"),
}
_ORIGINAL = {key: getattr(importlib.import_module(module), name) for key, (module, name) in SITES.items()}
# The digest of the source each was written from.
COPIED_FROM = {key: pyinfra_private.pinned(f"{module}:{name}") for key, (module, name) in SITES.items()}


digest = pyinfra_private.digest


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


def install() -> list[str]:
    """Replace what is still as it was copied; returns what is in place."""
    ours = {"order": operation_order_from_stack, "arguments": all_global_arguments}
    replaced = []
    for key, (module_name, name) in SITES.items():
        module = importlib.import_module(module_name)
        current = getattr(module, name)
        if current is not ours[key]:
            if digest(current) != COPIED_FROM[key]:
                logger.warning(f"robotfleet: pyinfra {pyinfra.__version__} has another {module_name}.{name} than "
                               "robotfleet/speedups.py was written from; pyinfra's own runs (slower, same answers)")
                continue
            setattr(module, name, ours[key])
        replaced.append(key)
    return replaced
