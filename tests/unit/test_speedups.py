"""robotfleet/speedups.py answers as pyinfra's own functions do, is active
with the pyinfra this project installs, and steps aside, with one line, on
a pyinfra whose functions changed."""

from __future__ import annotations

import importlib
import logging
import types

import pyinfra
import pytest
from pyinfra.api import arguments
from pyinfra.api import util as pyinfra_util

import robotfleet.provision  # noqa: F401 (installs the speedups, as a deploy does)
from robotfleet import speedups

operation = importlib.import_module("pyinfra.api.operation")  # pyinfra.api.operation is the decorator
pyinfra_order = speedups._ORIGINAL["order"]


def _nested(depth: int, call):
    # Several frames of this file between the caller and pyinfra, as deploy.py,
    # robotfleet/provision.py and a role's steps are.
    if depth:
        return _nested(depth - 1, call)
    return call()


@pytest.mark.parametrize("deploy_file", [__file__, None, "/nowhere/deploy.py"])
@pytest.mark.parametrize("is_cli", [True, False])
def test_operation_order_is_pyinfras(monkeypatch, deploy_file, is_cli):
    monkeypatch.setattr(pyinfra, "is_cli", is_cli)
    state = types.SimpleNamespace(current_deploy_filename=deploy_file, current_op_file_number=3)
    # Both called from the same line, so the stacks are the same but for the
    # functions' own frames.
    for _ in range(2):  # the second time from the places looked up the first
        theirs, ours = (_nested(4, lambda f=f: f(state)) for f in (pyinfra_order, speedups.operation_order_from_stack))
        assert ours == theirs
    if deploy_file == __file__:
        assert len(theirs) >= 5 + is_cli  # the line numbers of the nested calls at least


def test_global_arguments_are_pyinfras():
    ours = speedups.all_global_arguments()
    assert ours == speedups._ORIGINAL["arguments"]()
    assert "_sudo" in dict(ours)
    ours.clear()  # a caller's copy: the next call still has them all
    assert speedups.all_global_arguments() == speedups._ORIGINAL["arguments"]()


def test_the_speedups_are_active_with_the_pyinfra_this_project_installs():
    """No digest forced: the functions pyinfra calls are the copies."""
    assert operation.get_operation_order_from_stack is speedups.operation_order_from_stack
    assert arguments.all_global_arguments is speedups.all_global_arguments
    assert speedups.install() == ["order", "arguments"]  # a second install finds them in place


@pytest.fixture
def pyinfras_own(monkeypatch):
    """pyinfra's functions back where pyinfra calls them, as before any install."""
    monkeypatch.setattr(operation, "get_operation_order_from_stack", pyinfra_order)
    monkeypatch.setattr(arguments, "all_global_arguments", speedups._ORIGINAL["arguments"])


def test_install_replaces_what_pyinfra_calls(pyinfras_own, caplog):
    assert speedups.install() == ["order", "arguments"]
    assert operation.get_operation_order_from_stack is speedups.operation_order_from_stack
    assert arguments.all_global_arguments is speedups.all_global_arguments
    assert [r for r in caplog.records if "speedups" in r.getMessage()] == []


def test_a_pyinfra_whose_function_changed_keeps_its_own_with_one_line(pyinfras_own, monkeypatch, caplog):
    """An operator may install a later pyinfra 3.x.  Simulated: the operation
    module calls a changed function, while pyinfra.api.util still has the
    old one; the function checked is the one pyinfra calls, so it stays."""
    def get_operation_order_from_stack(state):  # a later pyinfra's
        return [state.current_op_file_number]

    monkeypatch.setattr(operation, "get_operation_order_from_stack", get_operation_order_from_stack)
    assert pyinfra_util.get_operation_order_from_stack is pyinfra_order  # the one the copy was written from
    caplog.set_level(logging.WARNING, logger="pyinfra")
    assert speedups.install() == ["arguments"]
    assert operation.get_operation_order_from_stack is get_operation_order_from_stack
    assert arguments.all_global_arguments is speedups.all_global_arguments
    lines = [r.getMessage() for r in caplog.records if "speedups" in r.getMessage()]
    assert lines == [f"robotfleet: pyinfra {pyinfra.__version__} has another "
                     "pyinfra.api.operation.get_operation_order_from_stack than robotfleet/speedups.py was written "
                     "from; pyinfra's own runs (slower, same answers)"]
