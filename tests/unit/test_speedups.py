"""robotfleet/speedups.py answers as pyinfra's own functions do."""

from __future__ import annotations

import types

import pyinfra
import pytest
from pyinfra.api import arguments

from robotfleet import speedups
from robotfleet.speedups import operation

pyinfra_order = speedups._ORIGINAL["order"]


def _nested(depth: int, call):
    # Several frames of this file between the caller and pyinfra, as deploy.py,
    # robotfleet/play.py and a role's steps are.
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


def test_install_replaces_pyinfras(monkeypatch):
    monkeypatch.setattr(operation, "get_operation_order_from_stack", pyinfra_order)
    monkeypatch.setattr(arguments, "all_global_arguments", speedups._ORIGINAL["arguments"])
    for name in ("order", "arguments"):  # as a pyinfra of its own would answer: pretend this one is theirs
        monkeypatch.setitem(speedups.COPIED_FROM, name, speedups.digest(speedups._ORIGINAL[name]))
    assert speedups.install() == ["order", "arguments"]
    assert operation.get_operation_order_from_stack is speedups.operation_order_from_stack
    assert arguments.all_global_arguments is speedups.all_global_arguments


def test_a_pyinfra_whose_functions_changed_keeps_its_own(monkeypatch):
    """An operator may install a later pyinfra 3.x: a function it changed is
    not replaced by a copy of the old one."""
    monkeypatch.setattr(operation, "get_operation_order_from_stack", pyinfra_order)
    monkeypatch.setattr(arguments, "all_global_arguments", speedups._ORIGINAL["arguments"])
    monkeypatch.setitem(speedups.COPIED_FROM, "order", "0" * 16)
    assert speedups.install() == ["arguments"]
    assert operation.get_operation_order_from_stack is pyinfra_order
    assert arguments.all_global_arguments is speedups.all_global_arguments

