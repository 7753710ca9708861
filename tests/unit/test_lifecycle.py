"""A release's life on the robot (payloadctl/lifecycle.py) as a state
machine: every transition from every state, and a power cut at every
durable step of each transition, after which the boot's recovery must leave
a consistent robot.  In process, on a temporary directory: the transitions
write files only (docker is not involved)."""

from __future__ import annotations

import ast
import contextlib
import os
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from roles.payload import installed_files as payload
from roles.payload.payloadctl import durable, lifecycle
from roles.payload.payloadctl.lifecycle import ACTIVE, FAILED, PREPARED, SETTLED, STAGED, STATES, SWITCHING, Life
from roles.payload.payloadctl.releases import Releases
from tests.fixtures import gevent_os_patched

LIFECYCLE = Path(lifecycle.__file__).resolve()


@pytest.fixture(autouse=True)
def _closes_at_once(monkeypatch):
    """payloadctl runs on robots, never under gevent.  In this process an
    earlier test's import of pyinfra's CLI may have patched ``os.close`` to
    close a directory only when gevent's loop next runs, which it never does
    here: one hypothesis test fsyncs directories thousands of times, past
    a soft limit of 1,024 open files within the test."""
    monkey = gevent_os_patched()
    if monkey:
        monkeypatch.setattr(os, "close", monkey.get_original("os", "close"))


class PowerCut(BaseException):
    """The power goes: nothing after this step happens (not an Exception:
    no handler of payloadctl's may catch it and tidy up)."""


@contextlib.contextmanager
def steps(cut_at=None, seen=None):
    """Count the durable steps (``seen``: each (step, path, writer)); with
    ``cut_at``, the power goes just before step number ``cut_at``.  fsync is
    skipped here: the order of the steps is what is tested, not the disk."""
    count = [0]

    def before_step(step, path):
        frame = sys._getframe(2)
        while os.path.basename(frame.f_code.co_filename) == "durable.py":
            frame = frame.f_back
        writer = Path(frame.f_code.co_filename).resolve()
        if seen is not None:
            seen.append((step, path, writer))
        if count[0] == cut_at:
            raise PowerCut(f"power cut before {step} {path}")
        count[0] += 1

    real_fsync = durable.os.fsync
    durable.before_step, durable.os.fsync = before_step, (lambda fd: None)
    try:
        yield count
    finally:
        durable.before_step, durable.os.fsync = None, real_fsync


def life_at(tmp_path) -> Life:
    root = tmp_path / "payload"
    root.mkdir(parents=True, exist_ok=True)
    return Life(Releases(str(root)))


def record(rid, **more):
    return lifecycle.Record(
        created=rid,
        spec_hash="h-" + rid,
        project="robot-payload",
        images={},
        autostart=True,
        deployed_by="test",
        run_id="run-" + rid,
        **more,
    )


def prepare(life, rid):
    return life.prepare(rid, {"name": "robot-payload"}, "# compose\n{}\n", record(rid))


def released(life, rid):
    """``rid`` made, switched to and verified (a deploy that succeeded)."""
    prepare(life, rid)
    life.switch(rid)
    return life.keep(rid)


def files(life) -> dict[str, str]:
    """Everything on disk under the payload directory (links as their target)."""
    found = {}
    for path in sorted(Path(life.root).rglob("*")):
        key = str(path.relative_to(life.root))
        if path.is_symlink():
            found[key] = "-> " + os.readlink(path)
        elif path.is_file():
            found[key] = path.read_text()
    return found


# --- every transition from every state ------------------------------------------


def release_in(life, state):
    """r1 verified and current, r2 in ``state`` reached the way a deploy
    reaches it (None: r2 does not exist)."""
    released(life, "r1")
    if state is None:
        return
    prepare(life, "r2")
    if state == PREPARED:
        return
    life.switch("r2")
    if state == ACTIVE:
        life.keep("r2")
    elif state == STAGED:
        life.stage("r2")
    elif state == FAILED:
        life.fail("r2", "unhealthy")


TRANSITIONS = {
    "prepare": lambda life: prepare(life, "r2"),
    "switch": lambda life: life.switch("r2"),
    "discard": lambda life: life.discard("r2"),
    "adopt": lambda life: life.adopt("r2", [{"name": "ros_payload", "why": "it runs the payload's image"}]),
    "keep": lambda life: life.keep("r2"),
    "stage": lambda life: life.stage("r2"),
    "fail": lambda life: life.fail("r2", "unhealthy"),
    "abandon": lambda life: life.abandon("r2"),
    "roll_back": lambda life: life.roll_back(),
    "recover": lambda life: life.recover(),
}
REFUSED = "refused"
# (r2's state before, transition) -> r2's state after; None: r2 is gone.
TABLE = {
    (None, "prepare"): PREPARED,
    (PREPARED, "switch"): SWITCHING,
    (PREPARED, "discard"): None,
    (SWITCHING, "adopt"): SWITCHING,
    (SWITCHING, "keep"): ACTIVE,
    (SWITCHING, "stage"): STAGED,
    (SWITCHING, "fail"): FAILED,
    (SWITCHING, "abandon"): SWITCHING,
    (ACTIVE, "roll_back"): SWITCHING,
    (STAGED, "roll_back"): SWITCHING,
    (FAILED, "roll_back"): SWITCHING,
    (SWITCHING, "recover"): FAILED,  # interrupted before its verdict: undone, back on r1
    **{(state, "recover"): state for state in (None, PREPARED, ACTIVE, STAGED, FAILED)},
}


@pytest.mark.parametrize("before", (None,) + STATES)
@pytest.mark.parametrize("transition", list(TRANSITIONS))
def test_every_transition_from_every_state(tmp_path, before, transition):
    life = life_at(tmp_path)
    release_in(life, before)
    if transition == "roll_back" and before is not None:  # r2 is the previous release, r1 current
        life._point("current", "r1")
        life._point("previous", "r2")
    expected = TABLE.get((before, transition), REFUSED)
    on_disk = files(life)
    seen = []
    if expected == REFUSED:
        with steps(seen=seen), pytest.raises(lifecycle.Refused):
            TRANSITIONS[transition](life)
        assert files(life) == on_disk and seen == []  # a refused transition writes nothing
        return
    with steps(seen=seen):
        TRANSITIONS[transition](life)
    assert life.state("r2") == expected
    assert {writer for _, _, writer in seen} <= {LIFECYCLE}
    will_be_undone_or_settled(life, first=False)  # mid-switch: what a cut here leaves, recovery undoes
    if transition == "recover":
        consistent(life)


def test_what_each_transition_leaves_in_the_pointers_and_records(tmp_path):
    life = life_at(tmp_path)
    released(life, "r1")
    assert (life.current(), life.previous()) == ("r1", None)
    prepare(life, "r2")
    switched = life.switch("r2")
    assert switched.switch == lifecycle.Switch("apply", "r1", None, None)
    assert (life.current(), life.previous()) == ("r2", "r1")
    assert life.fail("r2", "p is unhealthy") == "r1"
    assert (life.current(), life.previous()) == ("r1", None)
    assert life.record("r2").reason == "p is unhealthy" and life.record("r2").switch is None
    assert life.record("r1").rolled_back_from["id"] == "r2"
    released(life, "r3")
    assert (life.current(), life.previous()) == ("r3", "r1")
    target = life.roll_back()
    assert target.id == "r1" and target.switch.prior_state == ACTIVE
    assert (life.current(), life.previous()) == ("r1", "r3")
    assert life.fail("r1", "crash-looping") == "r3"  # all or nothing: back as it was
    assert (life.current(), life.previous()) == ("r3", "r1")
    assert life.state("r1") == ACTIVE and life.record("r1").rollback_failed["reason"] == "crash-looping"
    life.roll_back()
    life.keep("r1")
    assert (life.current(), life.previous()) == ("r1", "r3") and life.record("r1").rolled_back_to


def test_a_record_keeps_what_this_payloadctl_does_not_know(tmp_path):
    data = {"id": "r1", "state": "active", "created": "x", "from_the_future": {"a": 1}}
    assert lifecycle.Record.from_dict(data).to_dict() == data


# --- a power cut at every durable step --------------------------------------------


def update(life, outcome):
    prepare(life, "r2")
    life.switch("r2")
    life.adopt("r2", [{"name": "ros_payload", "why": "it runs the payload's image"}])
    {"keep": life.keep, "stage": life.stage}.get(outcome, lambda rid: life.fail(rid, "unhealthy"))("r2")


def first_release(life, outcome):
    prepare(life, "r1")
    life.switch("r1")
    if outcome == "give back":
        life.adopt("r1", [{"name": "ros_payload", "why": "it runs the payload's image"}])
        life.abandon("r1")
        life.fail(
            "r1", "unhealthy; restored what it had taken over: ros_payload", restored={"containers": ["ros_payload"]}
        )
    elif outcome == "keep":
        life.keep("r1")
    else:
        life.fail("r1", "unhealthy")


def manual_rollback(life, outcome):
    life.roll_back()
    (life.keep if outcome == "keep" else lambda rid: life.fail(rid, "crash-looping"))("r0")


SCENARIOS = {
    # name: (the robot before, the transitions, releases it may end on)
    "update kept": ("on r1", lambda life: update(life, "keep"), {"r1", "r2"}),
    "update staged": ("on r1", lambda life: update(life, "stage"), {"r1", "r2"}),
    "update failed": ("on r1", lambda life: update(life, "fail"), {"r1"}),
    "first release kept": ("empty", lambda life: first_release(life, "keep"), {None, "r1"}),
    "first release failed": ("empty", lambda life: first_release(life, "fail"), {None, "r1"}),
    "first release gave back": ("empty", lambda life: first_release(life, "give back"), {None, "r1"}),
    "rollback kept": ("r0 then r1", lambda life: manual_rollback(life, "keep"), {"r0", "r1"}),
    "rollback failed": ("r0 then r1", lambda life: manual_rollback(life, "fail"), {"r1"}),
}


def robot_before(life, how):
    if how in ("on r1", "r0 then r1"):
        if how == "r0 then r1":
            released(life, "r0")
        released(life, "r1")


def consistent(life, first=False):
    """What recovery must leave: every record readable with a known state;
    the pointers at releases that exist, apart; no switch half done;
    `current` verified, or a first release the next deploy verifies."""
    current, previous = life.current(), life.previous()
    for rid in life.releases.ids():
        found = life.record(rid)
        if found is None:
            assert rid not in (current, previous), rid  # a directory a cut left unfinished, never pointed at
            continue
        assert found.state in STATES, found
        if rid != current:
            assert found.switch is None and found.state != SWITCHING, found
    assert current is None or life.record(current) is not None
    assert previous is None or life.record(previous) is not None
    assert current is None or current != previous
    if current is not None and life.state(current) not in SETTLED:
        assert first, f"current {current} is {life.state(current)}"
        assert life.record(current).switch is None or life._usable(life.record(current)) is None


def will_be_undone_or_settled(life, first):
    """Before recovery: `current` is verified, or is in a switch recovery
    undoes, or is a first release (nothing to go back to)."""
    current = life.current()
    if current is None or life.state(current) in SETTLED:
        return
    assert life.record(current).switch is not None or first, (current, life.record(current))


def cut_and_recover(tmp_path, scenario, cut_at, recovery_cut=None):
    how, transitions, ends = SCENARIOS[scenario]
    life = life_at(tmp_path)
    robot_before(life, how)
    with steps(cut_at) as counted:
        try:
            transitions(life)
        except PowerCut:
            pass
    after_cut = counted[0]
    first = how == "empty"
    life = Life(Releases(life.root))  # the robot boots: nothing of the run is left in memory
    will_be_undone_or_settled(life, first)
    if recovery_cut is not None:
        with steps(recovery_cut):
            try:
                life.recover()
            except PowerCut:
                pass
    seen = []
    with steps(seen=seen):
        life.recover()
    assert {writer for _, _, writer in seen} <= {LIFECYCLE}
    consistent(life, first)
    assert life.current() in ends, (scenario, cut_at, life.current())
    on_disk = files(life)
    assert life.recover() is None and files(life) == on_disk  # recovery is done once
    return after_cut


def durable_steps(tmp_path, scenario) -> int:
    how, transitions, _ = SCENARIOS[scenario]
    life = life_at(tmp_path / "count")
    robot_before(life, how)
    with steps() as counted:
        transitions(life)
    return counted[0]


@pytest.mark.parametrize("scenario", list(SCENARIOS))
def test_a_power_cut_at_every_durable_step_is_recovered(tmp_path, scenario):
    total = durable_steps(tmp_path, scenario)
    assert total >= 6
    for cut_at in range(total + 1):  # total: no cut at all
        cut_and_recover(tmp_path / f"cut{cut_at}", scenario, cut_at)


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(scenario=st.sampled_from(sorted(SCENARIOS)), cut_at=st.integers(0, 40), recovery_cut=st.integers(0, 12))
def test_a_power_cut_during_the_recovery_of_a_power_cut(tmp_path_factory, scenario, cut_at, recovery_cut):
    cut_and_recover(tmp_path_factory.mktemp("cut"), scenario, cut_at, recovery_cut)


OPERATIONS = ("update kept", "update staged", "update failed", "rollback kept", "rollback failed")


def operate(life, operation):
    """What payloadctl does for one deploy or rollback, recovery first (as
    every holder of the apply lock does); a rollback with nothing to roll
    back to is refused before anything is written."""
    life.recover()
    if operation.startswith("update"):
        rid = "r{}".format(len(life.releases.ids()) + 1)
        prepare(life, rid)
        life.switch(rid)
        outcome = operation.split()[1]
        {"kept": life.keep, "staged": life.stage}.get(outcome, lambda r: life.fail(r, "unhealthy"))(rid)
        return
    previous = life.previous()
    if previous is None or life.state(previous) not in (ACTIVE, STAGED, FAILED):
        return
    life.roll_back()
    (life.keep if operation == "rollback kept" else lambda r: life.fail(r, "crash-looping"))(previous)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    operations=st.lists(st.sampled_from(OPERATIONS), min_size=1, max_size=6),
    cut_at=st.integers(0, 80),
    recovery_cut=st.one_of(st.none(), st.integers(0, 12)),
)
def test_any_history_cut_anywhere_recovers_to_a_consistent_robot(tmp_path_factory, operations, cut_at, recovery_cut):
    life = life_at(tmp_path_factory.mktemp("history"))
    released(life, "r1")
    with steps(cut_at):
        try:
            for operation in operations:
                operate(life, operation)
        except PowerCut:
            pass
    life = Life(Releases(life.root))
    will_be_undone_or_settled(life, first=False)
    if recovery_cut is not None:
        with steps(recovery_cut):
            try:
                life.recover()
            except PowerCut:
                pass
    life.recover()
    consistent(life)


# --- nothing else writes a record or moves a pointer -------------------------------

PAYLOADCTL = Path(payload.PACKAGE)
WRITERS = ("lifecycle.py", "durable.py")


def offences(source: str) -> list[tuple[int, str]]:
    """Where ``source`` writes a record or a pointer: names record.json
    other than to read it (durable.read_json) or in a docstring, makes a
    link, calls the durable steps of lifecycle, or writes, replaces or
    removes a path built from current, previous or a record."""
    tree = ast.parse(source)
    parents = {child: node for node in ast.walk(tree) for child in ast.iter_child_nodes(node)}

    def read_only(node):
        while node in parents:
            node = parents[node]
            if isinstance(node, ast.Expr):
                return True  # a docstring
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "read_json":
                return True
        return False

    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and "record.json" in node.value:
            if not read_only(node):
                found.append((node.lineno, "names record.json"))
        if isinstance(node, ast.Attribute) and node.attr in ("symlink", "_write", "_point", "write_record", "point"):
            found.append((node.lineno, node.attr))
        if (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Attribute)
            and node.func.attr in ("write_json", "write_text", "write_bytes", "unlink", "replace", "rename", "rmtree")
        ):
            target = ast.unparse(node.args[0]) if node.args else ""
            if any(word in target for word in ('"current"', '"previous"', "record", "pointer")):
                found.append((node.lineno, ast.unparse(node)))
    return found


def test_only_lifecycle_writes_records_and_pointers():
    """Every other module of payloadctl reads records and pointers only."""
    found = {
        path.name: offences(path.read_text()) for path in sorted(PAYLOADCTL.glob("*.py")) if path.name not in WRITERS
    }
    assert {name: lines for name, lines in found.items() if lines} == {}


def test_the_ownership_check_finds_a_writer():
    """It finds lifecycle.py's own writes, and the ways the other modules
    used to write: takeover.py its record, apply.py and recovery.py the
    pointers."""
    assert len(offences(LIFECYCLE.read_text())) >= 5
    for old in (
        'durable.write_json(releases.path(rid, "record.json"), record)\n',
        'releases.point("current", good_old)\n',
        "releases.write_record(rid, record)\n",
        'os.symlink(os.path.join("releases", rid), tmp)\n',
    ):
        assert offences(old), old
