"""Property-style: random and mutated fleet documents are either accepted or
refused with problem lines that each name the file and a host/field (or a
YAML line); never a traceback, never a hang, never a connection (pyinfra's
own CLI on such documents: tests/integration/test_fleet_fuzz.py).

Documents come from stdlib `random` with fixed seeds, so a failure replays:
the assertion message carries the seed and the document.
"""

from __future__ import annotations

import pytest

from tests.unit import harness as fleet
from tests.unit.fleetfuzz import (
    DOCUMENTS,
    HANG_SECONDS,
    SHOWN,
    assert_problem_lines,
    documents,
    good_fleet,
    hang_guard,
    outcome,
)


@pytest.mark.parametrize("seed", [1, 2])
def test_random_documents_are_accepted_or_refused_with_problem_lines(seed):
    accepted = refused = 0
    for label, data in documents(9, DOCUMENTS // 2, seed):
        lines = outcome(data)
        if lines is None:
            accepted += 1
        else:
            refused += 1
            assert_problem_lines(lines, label, data)
    assert accepted and refused  # the generator reaches both sides


WRONG_TYPES = [
    -1,
    2**70,
    float("nan"),
    False,
    None,
    "",
    "x" * 500,
    [[[]]],
    {1: 2},
    {"a": {"b": [None]}},
    [{"name": None}],
    "\n",
]


def test_wrong_types_at_every_setting_in_every_layer():
    """The sweep behind the random documents: each setting, each layer, each
    kind of value: a file+field line or acceptance, nothing else."""
    for setting in fleet.setting_checks():
        for value in WRONG_TYPES:
            for layer in ("all.vars", "host"):
                doc = good_fleet(9)
                target = (
                    doc["robots"]["hosts"]["r0"] if layer == "host" else doc[layer.split(".")[0]].setdefault("vars", {})
                )
                target[setting] = value
                try:
                    with hang_guard(HANG_SECONDS):
                        fleet.check(doc, SHOWN)
                except fleet.FleetError as error:
                    assert_problem_lines(error.lines, f"{setting}={value!r} in {layer}", b"")
