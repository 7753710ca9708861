"""robotfleet/pyinfra_patches.py answers as pyinfra's own functions do, is active
with the pyinfra this project installs, and steps aside, with one line, on
a pyinfra whose functions changed."""

from __future__ import annotations

import importlib
import inspect
import logging
import types

import pyinfra
import pytest
from pyinfra.api import arguments
from pyinfra.api import connectors as pyinfra_connectors
from pyinfra.api import util as pyinfra_util
from pyinfra.api.inventory import Inventory

import robotfleet.provision  # noqa: F401 (installs the patches, as a deploy does)
from robotfleet import pyinfra_patches

operation = importlib.import_module("pyinfra.api.operation")  # pyinfra.api.operation is the decorator
pyinfra_order = pyinfra_patches.original("order")


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
        theirs, ours = (
            _nested(4, lambda f=f: f(state)) for f in (pyinfra_order, pyinfra_patches.operation_order_from_stack)
        )
        assert ours == theirs
    if deploy_file == __file__:
        assert len(theirs) >= 5 + is_cli  # the line numbers of the nested calls at least


def test_connectors_are_pyinfras(monkeypatch):
    monkeypatch.setattr(pyinfra_connectors, "entry_points", pyinfra_patches.original("connectors"))
    theirs = pyinfra_connectors.get_all_connectors()
    monkeypatch.setattr(pyinfra_connectors, "entry_points", pyinfra_patches.entry_points)
    assert pyinfra_connectors.get_all_connectors() == theirs
    assert pyinfra_connectors.get_all_connectors() == theirs  # from the entry points read once
    assert {"ssh", "local", "fleet"} <= set(theirs)


def test_signatures_are_inspects_and_made_once():
    from pyinfra.operations import apt, files

    for function in (files.put, apt.packages, _nested):
        assert pyinfra_patches.signature(function) == inspect.signature(function)
        assert pyinfra_patches.signature(function) is pyinfra_patches.signature(function)
    pyinfra_patches.signature(files.directory).bind("/etc/x", present=True)
    refusals = []
    for made in (inspect.signature, pyinfra_patches.signature):
        with pytest.raises(TypeError) as refused:
            made(files.directory).bind("/etc/x", nothing=1)
        refusals.append(str(refused.value))
    assert refusals[0] == refusals[1] and "nothing" in refusals[0]


def test_global_arguments_from_layered_host_data_are_pyinfras():
    """Every layer of host data (override, host, groups, inventory, @deploy
    data), arguments given to the operation and to its @deploy, a handler
    (_env), and a bad type: the same answer and the same kwargs left."""
    from pyinfra.api import Config, State
    from pyinfra.api.exceptions import ArgumentTypeError

    inventory = Inventory(
        (["h1"], {"_sudo_user": "from-inventory", "_timeout": 5}),
        robots=(["h1"], {"_sudo": True, "_timeout": 7, "_env": {"A": "group"}, "other": 1}),
        site=(["h1"], {"_sudo_user": "from-site"}),
    )
    state = State(inventory, Config())
    host = inventory.get_host("h1")
    host.data._use_sudo_password = False  # the override layer
    pyinfras = pyinfra_patches.original("pop_arguments")
    cases = [{}, {"_sudo": False, "_env": {"B": "op"}, "keep": 1}, {"_timeout": 9, "_serial": True}]
    for deploy_kwargs in (None, {"_sudo_user": "from-deploy", "_retries": 2}):
        host.current_deploy_kwargs = deploy_kwargs
        for kwargs in cases:
            theirs_kwargs, ours_kwargs = dict(kwargs), dict(kwargs)
            theirs = pyinfras(state, host, theirs_kwargs)
            ours = pyinfra_patches.pop_global_arguments(state, host, ours_kwargs)
            assert ours == theirs and ours_kwargs == theirs_kwargs
    assert ours[0]["_sudo_user"] == "from-deploy" and ours[0]["_timeout"] == 9
    for pop in (pyinfras, pyinfra_patches.pop_global_arguments):
        with pytest.raises(ArgumentTypeError, match="Invalid argument `_timeout`"):
            pop(state, host, {"_timeout": "soon"})
    # No argument name is an attribute of HostData itself (getattr would find that first).
    assert not {key for key, _ in arguments.all_global_arguments()} & set(dir(host.data))


ALL = ["order", "connectors", "pop_arguments", "signature"]


def test_the_speedups_are_active_with_the_pyinfra_this_project_installs():
    """No digest forced: the functions pyinfra calls are the copies."""
    assert operation.get_operation_order_from_stack is pyinfra_patches.operation_order_from_stack
    assert pyinfra_patches.install() == ALL  # a second install finds them in place
    assert pyinfra_connectors.entry_points is pyinfra_patches.entry_points
    assert operation.signature is pyinfra_patches.signature
    for module in ("operation", "deploy", "facts"):
        own = importlib.import_module(f"pyinfra.api.{module}").pop_global_arguments
        assert own is pyinfra_patches.pop_global_arguments


@pytest.fixture
def pyinfras_own(monkeypatch):
    """pyinfra's functions back where pyinfra calls them, as before any install."""
    for speedup in pyinfra_patches.SPEEDUPS.values():
        for site in speedup.sites:
            monkeypatch.setattr(*pyinfra_patches._owner(site), pyinfra_patches._ORIGINAL[site])


def _lines(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if "pyinfra_patches" in r.getMessage()]


def test_install_replaces_what_pyinfra_calls(pyinfras_own, caplog):
    assert operation.signature is inspect.signature
    assert pyinfra_patches.install() == ALL
    assert operation.get_operation_order_from_stack is pyinfra_patches.operation_order_from_stack
    assert operation.signature is pyinfra_patches.signature
    assert _lines(caplog) == []


def test_a_pyinfra_whose_function_changed_keeps_its_own_with_one_line(pyinfras_own, monkeypatch, caplog):
    """An operator may install a later pyinfra 3.x.  Simulated: the operation
    module calls a changed function, while pyinfra.api.util still has the
    old one; the function checked is the one pyinfra calls, so it stays."""

    def get_operation_order_from_stack(state):  # a later pyinfra's
        return [state.current_op_file_number]

    monkeypatch.setattr(operation, "get_operation_order_from_stack", get_operation_order_from_stack)
    assert pyinfra_util.get_operation_order_from_stack is pyinfra_order  # the one the copy was written from
    caplog.set_level(logging.WARNING, logger="pyinfra")
    assert pyinfra_patches.install() == ALL[1:]
    assert operation.get_operation_order_from_stack is get_operation_order_from_stack
    assert _lines(caplog) == [
        f"robotfleet: pyinfra {pyinfra.__version__} has another "
        "pyinfra.api.operation.get_operation_order_from_stack than "
        "robotfleet/pyinfra_patches.py was written from; pyinfra's own runs (slower, "
        "same answers)"
    ]


def test_a_changed_host_data_lookup_keeps_pyinfras_argument_reading(pyinfras_own, monkeypatch, caplog):
    """The copy of pop_global_arguments looks host data up as
    HostData.__getattr__ does: a pyinfra that changed that keeps its own."""
    monkeypatch.setitem(pyinfra_patches.COPIED_FROM, "pyinfra.api.host:HostData.__getattr__", "0" * 16)
    caplog.set_level(logging.WARNING, logger="pyinfra")
    assert pyinfra_patches.install() == ["order", "connectors", "signature"]
    assert operation.pop_global_arguments is pyinfra_patches.original("pop_arguments")
    assert _lines(caplog) == [
        f"robotfleet: pyinfra {pyinfra.__version__} has another "
        "pyinfra.api.host.HostData.__getattr__ than robotfleet/pyinfra_patches.py was written "
        "from; pyinfra's own runs (slower, same answers)"
    ]


def test_a_changed_caller_or_another_function_where_it_calls_keeps_pyinfras(pyinfras_own, monkeypatch, caplog):
    """get_all_connectors changed (the entry_points it calls is importlib's,
    unchanged), then unchanged but calling another entry_points."""
    monkeypatch.setitem(pyinfra_patches.COPIED_FROM, "pyinfra.api.connectors:get_all_connectors", "0" * 16)
    caplog.set_level(logging.WARNING, logger="pyinfra")
    assert "connectors" not in pyinfra_patches.install()
    assert pyinfra_connectors.entry_points is pyinfra_patches.original("connectors")
    assert "pyinfra.api.connectors.get_all_connectors" in _lines(caplog)[0]
    monkeypatch.setitem(
        pyinfra_patches.COPIED_FROM,
        "pyinfra.api.connectors:get_all_connectors",
        pyinfra_patches.digest(pyinfra_connectors.get_all_connectors),
    )

    def entry_points(group):  # not importlib's
        return []

    monkeypatch.setattr(pyinfra_connectors, "entry_points", entry_points)
    assert "connectors" not in pyinfra_patches.install()
    assert pyinfra_connectors.entry_points is entry_points
