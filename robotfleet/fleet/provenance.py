"""Where a host's settings come from (robotfleet/fleet/tree.py ``Tree.sourced``
orders its layers as Ansible does), and where sibling groups disagree.

A host in two groups of the same depth (``warehouse_a`` and ``lidar_bots``)
that set one setting differently gets one of the values by Ansible's rule
(group_vars/ files above the inventory's own vars, then the higher
``ansible_group_priority``, then the later name), silently in Ansible;
``disagreements`` says which group won and why, for a note.  Pure: the
caller says what each layer sets (``named``: setting -> value, under the
settings' own names).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from robotfleet.fleet.tree import ALL, Layer, Tree


@dataclass(frozen=True)
class Origin:
    """One layer's value of a setting: whose (``group robots``, ``host robot1``) and where."""

    who: str
    at: str  # file[:line]
    value: tuple  # (the key as written, its value)


@dataclass(frozen=True)
class Disagreement:
    setting: str
    winner: str  # the group whose value the host gets
    losers: tuple[str, ...]  # sibling groups whose different value it does not
    why: str
    at: str  # where the winning value is written


def origins(tree: Tree, host: str, named: Callable[[Layer], dict]) -> dict[str, list[Origin]]:
    """Each setting ``host``'s layers set -> every layer that sets it, lowest
    first (the last wins, unless the setting merges its layers); ``named``:
    setting -> (the key as written, its value), whose line is shown."""
    found: dict[str, list[Origin]] = {}
    for kind, name, layer in tree.sourced(host):
        for setting, value in named(layer).items():
            found.setdefault(setting, []).append(Origin(f"{kind} {name}", layer.source(value[0]), value))
    return found


def _siblings_possible(tree: Tree, host: str) -> bool:
    """Whether ``host`` is in two groups of one depth at all (most hosts are not: the check stops there)."""
    depths = [tree.depth(group) for group in tree.above(host) - {ALL}]
    return len(depths) != len(set(depths))


def disagreements(tree: Tree, host: str, named: Callable[[Layer], dict], merged=frozenset()) -> list[Disagreement]:
    """The settings ``host`` gets from one of several sibling groups (same
    depth) that set it differently; ``merged``: settings whose layers
    combine, never disagreeing."""
    if not _siblings_possible(tree, host):
        return []
    sourced = tree.sourced(host)
    last: dict[str, int] = {}
    for index, (_, _, layer) in enumerate(sourced):
        for setting in named(layer):
            last[setting] = index
    found = []
    for setting, index in last.items():
        kind, winner, layer = sourced[index]
        if kind != "group" or winner == ALL or setting in merged:
            continue
        value = named(layer)[setting]
        depth = tree.depth(winner)
        losers = {
            name: other
            for k, name, other in sourced[:index]
            if k == "group"
            and name != winner
            and tree.depth(name) == depth
            and setting in named(other)
            and named(other)[setting] != value
        }
        if losers:
            why = "; ".join(dict.fromkeys(_why(tree, winner, layer, name, other) for name, other in losers.items()))
            found.append(Disagreement(setting, winner, tuple(sorted(losers)), why, layer.at(setting)))
    return found


def _why(tree: Tree, winner: str, won: Layer, loser: str, lost: Layer) -> str:
    """Why Ansible gives the host ``winner``'s value over ``loser``'s."""
    if any(won is f for f in tree.groups[winner].files) and not any(lost is f for f in tree.groups[loser].files):
        return f"group_vars/{winner} is read after the inventory's own vars of {loser}"
    if tree.priority(winner) != tree.priority(loser):
        return f"ansible_group_priority {tree.priority(winner)} over {tree.priority(loser)}"
    return f"same depth and ansible_group_priority: {winner} sorts after {loser} by name"
