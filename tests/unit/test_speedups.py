"""robotfleet/speedups.py answers as pyinfra's own functions do."""

from __future__ import annotations

import types

import pyinfra
import pytest
from pyinfra.api import arguments
from pyinfra.api import connectors as pyinfra_connectors
from pyinfra.api.host import HostData
from pyinfra.api.inventory import Inventory

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


def _pyinfras_own(monkeypatch):
    monkeypatch.setattr(operation, "get_operation_order_from_stack", pyinfra_order)
    monkeypatch.setattr(arguments, "all_global_arguments", speedups._ORIGINAL["arguments"])
    monkeypatch.setattr(pyinfra_connectors, "entry_points", speedups._ENTRY_POINTS)
    monkeypatch.setattr(Inventory, "get_groups_data", speedups._ORIGINAL["groups_data"])
    for module in speedups._POP_USERS:
        monkeypatch.setattr(module, "pop_global_arguments", speedups._ORIGINAL["pop_arguments"])
    monkeypatch.setattr(HostData, "__getattr__", speedups._ORIGINAL["host_data"])


def test_install_replaces_pyinfras(monkeypatch):
    _pyinfras_own(monkeypatch)
    for name in speedups.COPIED_FROM:  # as a pyinfra of its own would answer: pretend this one is theirs
        monkeypatch.setitem(speedups.COPIED_FROM, name, speedups.digest(speedups._ORIGINAL[name]))
    assert speedups.install() == ["order", "arguments", "connectors", "groups_data", "pop_arguments", "host_data"]
    assert operation.get_operation_order_from_stack is speedups.operation_order_from_stack
    assert arguments.all_global_arguments is speedups.all_global_arguments
    assert pyinfra_connectors.entry_points is speedups.entry_points
    assert Inventory.get_groups_data is speedups.groups_data


def test_a_pyinfra_whose_functions_changed_keeps_its_own(monkeypatch):
    """An operator may install a later pyinfra 3.x: a function it changed is
    not replaced by a copy of the old one."""
    _pyinfras_own(monkeypatch)
    monkeypatch.setitem(speedups.COPIED_FROM, "order", "0" * 16)
    monkeypatch.setitem(speedups.COPIED_FROM, "groups_data", "0" * 16)
    assert speedups.install() == ["arguments", "connectors", "pop_arguments", "host_data"]
    assert Inventory.get_groups_data is speedups._ORIGINAL["groups_data"]
    assert operation.get_operation_order_from_stack is pyinfra_order
    assert arguments.all_global_arguments is speedups.all_global_arguments



def test_connectors_are_pyinfras(monkeypatch):
    theirs = speedups._ORIGINAL["connectors"]()
    monkeypatch.setattr(pyinfra_connectors, "entry_points", speedups.entry_points)
    assert pyinfra_connectors.get_all_connectors() == theirs
    assert pyinfra_connectors.get_all_connectors() == theirs  # from the entry points read once
    assert {"ssh", "local", "fleet"} <= set(theirs)


def test_groups_data_is_pyinfras_for_each_inventory():
    def inventory(value):
        return Inventory((["h1", "h2"], {}), robots=(["h1"], {"a": value, "b": 2}), site=(["h1"], {"a": 3}))

    first, second = inventory(1), inventory(10)
    for groups in (["robots"], ["robots", "site"], ["site", "robots"], [], ["nowhere"]):
        theirs = speedups._ORIGINAL["groups_data"](first, groups)
        assert speedups.groups_data(first, groups) == speedups.groups_data(first, groups) == theirs
    assert speedups.groups_data(second, ["robots"]) == {"a": 10, "b": 2}  # each inventory its own


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
    pyinfras = speedups._ORIGINAL["pop_arguments"]
    cases = [{}, {"_sudo": False, "_env": {"B": "op"}, "keep": 1}, {"_timeout": 9, "_serial": True}]
    for deploy_kwargs in (None, {"_sudo_user": "from-deploy", "_retries": 2}):
        host.current_deploy_kwargs = deploy_kwargs
        for kwargs in cases:
            theirs_kwargs, ours_kwargs = dict(kwargs), dict(kwargs)
            theirs = pyinfras(state, host, theirs_kwargs)
            ours = speedups.pop_global_arguments(state, host, ours_kwargs)
            assert ours == theirs and ours_kwargs == theirs_kwargs
    assert ours[0]["_sudo_user"] == "from-deploy" and ours[0]["_timeout"] == 9
    for pop in (pyinfras, speedups.pop_global_arguments):
        with pytest.raises(ArgumentTypeError, match="Invalid argument `_timeout`"):
            pop(state, host, {"_timeout": "soon"})
    # No argument name is an attribute of HostData itself (getattr would find that first).
    assert not {key for key, _ in speedups.all_global_arguments()} & set(dir(host.data))


def test_host_data_lookups_are_pyinfras():
    from collections import OrderedDict

    inventory = Inventory((["h1"], {"everywhere": "inventory", "deep": [1, 2]}),
                          robots=(["h1"], {"everywhere": "group", "group_only": {"a": 1}}))
    host = inventory.get_host("h1")
    host.data.everywhere = "override"
    host.data.__dict__["datas"] += (OrderedDict(mapping_only=3),)  # a layer that is no plain dict
    theirs = speedups._ORIGINAL["host_data"]
    for key in ("everywhere", "group_only", "deep", "mapping_only"):
        ours = speedups.host_data_getattr(host.data, key)
        assert ours == theirs(host.data, key)
    assert speedups.host_data_getattr(host.data, "deep") is not inventory.get_data()["deep"]  # a copy, as theirs
    for lookup in (theirs, speedups.host_data_getattr):
        with pytest.raises(AttributeError, match="Host `h1` has no data `nowhere`"):
            lookup(host.data, "nowhere")
