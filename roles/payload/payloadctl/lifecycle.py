"""A release's life on this robot: its record (record.json), the `current`
and `previous` pointers, and every transition between its states.  Nothing
else writes a record or moves a pointer (tests/unit/test_lifecycle.py holds
every other module to it).

    prepare   (new)      -> prepared   the release directory, written whole
    switch    prepared   -> switching  `current` moves to it; the switch note says where from
    adopt     switching  -> switching  what it takes over, recorded before it is stopped
    keep      switching  -> active     verified healthy
    stage     switching  -> staged     in place without autostart (laptops)
    fail      switching  -> failed     and back on where it came from, if that can run
    roll_back settled    -> switching  a manual rollback to `previous` (all or nothing)
    recover   any                      at boot and before each change: finish or undo a
                                       switch a power cut or crash left half done

A switch note stays in a record from the switch until its end (keep, stage,
or the way back).  Each step is durable (durable.py), and a power cut
between any two leaves a state recover() turns into a settled one: current
verified, or a first release (nothing to go back to) that runs unverified
until the next deploy verifies it."""

import collections
import os
import shutil

from . import durable
from .system import now, precise_now

# A release's states (record.json "state"):
PREPARED = "prepared"  # written, not yet switched to
SWITCHING = "switching"  # current points at it, not yet verified (a power cut here is undone at boot)
ACTIVE = "active"  # verified healthy and running
STAGED = "staged"  # in place without autostart (laptops): nothing to verify
FAILED = "failed"  # failed its health gate or was interrupted before it
STATES = (PREPARED, SWITCHING, ACTIVE, STAGED, FAILED)
SETTLED = (ACTIVE, STAGED)  # passed its gate: what a deploy or a rollback may go back to
INTERRUPTED = "interrupted before it was verified healthy (power cut, reboot or crash)"


class Refused(ValueError):
    """A transition asked of a release in a state it does not leave that way."""


class Switch(collections.namedtuple("Switch", ("kind", "came_from", "previous_before", "prior_state"))):
    """A switch in progress: "apply" or "rollback", the release `current`
    pointed at before (None: nothing verified to go back to), `previous`
    before, and (rollback) the state the target had."""

    __slots__ = ()

    @classmethod
    def from_dict(cls, data):
        return cls(data.get("kind") or "apply", data.get("from"), data.get("previous_before"), data.get("prior_state"))

    def to_dict(self):
        found = {"kind": self.kind, "from": self.came_from, "previous_before": self.previous_before}
        if self.prior_state is not None:
            found["prior_state"] = self.prior_state
        return found


FIELDS = (
    "id",
    "created",
    "spec_hash",
    "project",
    "images",
    "deployed_by",
    "autostart",
    "run_id",
    "state",
    "switch",
    "switched",
    "activated",
    "failed",
    "reason",
    "rolled_back_from",
    "rolled_back_to",
    "rollback_failed",
    "rollback_interrupted",
    "taken_over",
    "restored",
)


class Record(collections.namedtuple("Record", FIELDS + ("extra",), defaults=(None,) * (len(FIELDS) + 1))):
    """A release's record.  Absent fields are None (and left out of the
    file); fields this payloadctl does not know are kept in ``extra``."""

    __slots__ = ()

    @classmethod
    def from_dict(cls, data):
        known = {name: data.get(name) for name in FIELDS}
        if isinstance(known["switch"], dict):
            known["switch"] = Switch.from_dict(known["switch"])
        elif known["switch"] is not None:
            known["switch"] = None
        return cls(extra={k: v for k, v in data.items() if k not in FIELDS} or None, **known)

    def to_dict(self):
        found = dict(self.extra or {})
        for name in FIELDS:
            value = getattr(self, name)
            if value is not None:
                found[name] = value.to_dict() if name == "switch" else value
        return found


class Life:
    """The releases of one robot (``releases``, a releases.Releases) and
    every change to them."""

    def __init__(self, releases):
        self.releases = releases
        self.root = releases.root

    # --- reading -------------------------------------------------------------

    def record(self, rid):
        data = self.releases.raw_record(rid)
        return Record.from_dict(data) if data is not None else None

    def state(self, rid):
        record = self.record(rid)
        return record.state if record else None

    def current(self):
        return self.releases.pointer("current")

    def previous(self):
        return self.releases.pointer("previous")

    # --- the durable steps (the only writers of records and pointers) -------

    def _write(self, record):
        durable.write_json(self.releases.path(record.id, "record.json"), record.to_dict())
        return record

    def _point(self, name, rid):
        link = os.path.join(self.root, name)
        if rid is None:
            if os.path.lexists(link):
                durable.unlink(link)
            return
        if self.releases.pointer(name) != rid or not os.path.islink(link):
            durable.symlink(os.path.join("releases", rid), link)

    def _expect(self, rid, *states):
        record = self.record(rid)
        if record is None or record.state not in states:
            raise Refused(
                "release {} is {}, not {}".format(rid, record.state if record else "missing", " or ".join(states))
            )
        return record

    # --- the transitions -----------------------------------------------------

    def prepare(self, rid, spec_dict, compose_text, record):
        """A new release's directory, written whole or not at all (a write
        that fails, disk full, leaves nothing behind)."""
        if os.path.lexists(self.releases.path(rid)):
            raise Refused("release {} exists already".format(rid))
        try:
            durable.make_private_dir(self.releases.path(rid))
            durable.write_text(self.releases.path(rid, "compose.yaml"), compose_text)
            durable.write_json(self.releases.path(rid, "spec.json"), spec_dict)
            return self._write(record._replace(id=rid, state=PREPARED, switch=None))
        except OSError:
            shutil.rmtree(self.releases.path(rid), ignore_errors=True)
            raise

    def discard(self, rid):
        """A prepared release that will never run (its compose file refused)."""
        self._expect(rid, PREPARED)
        shutil.rmtree(self.releases.path(rid), ignore_errors=True)

    def switch(self, rid):
        """`current` moves to a prepared release; the release it leaves
        becomes `previous` when it was verified, and is where a failure goes
        back to."""
        record = self._expect(rid, PREPARED)
        old = self.current()
        good_old = old if old and old != rid and self.state(old) in SETTLED else None
        switch = Switch("apply", good_old, self.previous(), None)
        record = self._write(record._replace(state=SWITCHING, switch=switch, switched=precise_now()))
        if good_old:
            self._point("previous", good_old)
        self._point("current", rid)
        return record

    def roll_back(self):
        """A manual rollback: `current` and `previous` swap; the target is
        unverified until kept (all or nothing: a failure swaps them back)."""
        current, previous = self.current(), self.previous()
        target = self._expect(previous, ACTIVE, STAGED, FAILED) if previous else None
        if target is None or current is None:
            raise Refused("no previous release to roll back to")
        switch = Switch("rollback", current, previous, target.state)
        target = self._write(target._replace(state=SWITCHING, switch=switch, switched=precise_now()))
        self._point("current", previous)
        self._point("previous", current)
        return target

    def adopt(self, rid, taken_over):
        """What the release takes over, recorded before it is stopped."""
        record = self._expect(rid, SWITCHING)
        return self._write(record._replace(taken_over=list(taken_over)))

    def keep(self, rid):
        record = self._expect(rid, SWITCHING)
        rolled_back = record.switch and record.switch.kind == "rollback"
        stamp = {"rolled_back_to": now()} if rolled_back else {"activated": now()}
        return self._write(record._replace(state=ACTIVE, switch=None, **stamp))

    def stage(self, rid):
        record = self._expect(rid, SWITCHING)
        stamp = {"rolled_back_to": now()} if record.switch and record.switch.kind == "rollback" else {}
        return self._write(record._replace(state=STAGED, switch=None, **stamp))

    def abandon(self, rid):
        """A first release failed and gives back what it took over: nothing
        of ours is current any more (before the others start again)."""
        self._expect(rid, SWITCHING)
        if self.current() == rid:
            self._point("current", None)

    def fail(self, rid, why, restored=None):
        """The release failed its gate: record why and switch back to where
        it came from.  Returns the release now current when it went back."""
        record = self._expect(rid, SWITCHING)
        if restored is not None:
            record = record._replace(restored=restored)
        return self._back(self._write(_verdict(record, why, failed=True)))

    def recover(self):
        """Finish or undo every switch a power cut or crash left half done;
        a line for the log when `current` went back, else None."""
        current = self.current()
        said = None
        for rid in self.releases.ids():
            record = self.record(rid)
            if record is None or record.switch is None:
                continue
            if record.state == SWITCHING and rid != current:  # cut before `current` moved to it
                self._pointers_back(record)
                self._write(_verdict(record, INTERRUPTED, failed=False, ran=False)._replace(switch=None))
                continue
            if record.state == SWITCHING and not self._usable(record):
                continue  # a first release: run as it is, the next deploy verifies it
            why = INTERRUPTED
            if record.state == SWITCHING:
                record = self._write(_verdict(record, INTERRUPTED, failed=False))
            elif record.switch.kind == "rollback" and record.rollback_failed:
                why = "failed ({})".format(record.rollback_failed.get("reason"))
            elif record.state == FAILED:
                why = "failed ({})".format(record.reason)
            back = self._back(record)
            if back and rid == current:
                said = "payload: release {} was {}; back on {}".format(rid, why, back)
        return said

    # --- the way back, written once -------------------------------------------

    def _usable(self, record):
        """Where ``record``'s switch can go back to: the release it left,
        when that is still there (and verified, for an update)."""
        back = record.switch.came_from
        if not back or back == record.id:
            return None
        state = self.state(back)
        if state is None or (record.switch.kind == "apply" and state not in SETTLED):
            return None
        return back

    def _pointers_back(self, record):
        """`current` back where ``record``'s switch came from and `previous`
        as it was (when `current` is at either end of the switch)."""
        back = self._usable(record)
        if back and self.current() in (record.id, back):
            self._point("current", back)
            self._point("previous", record.switch.previous_before)
            return back
        return None

    def _back(self, record):
        """The way back after a release ran: pointers back, the release gone
        back to told why, then the switch note goes.  Each step is
        idempotent: recover() finishes what a power cut cut short."""
        back = self._pointers_back(record)
        if back:
            self._told(back, record)
        self._write(record._replace(switch=None))
        return back

    def _told(self, back, record):
        """The release gone back to records where from and why (once)."""
        target = self.record(back)
        if (target.rolled_back_from or {}).get("id") == record.id:
            return
        why = record.reason
        if record.switch.kind == "rollback":
            why = (record.rollback_failed or record.rollback_interrupted or {}).get("reason")
        self._write(target._replace(rolled_back_from={"id": record.id, "reason": why or INTERRUPTED, "time": now()}))


def _verdict(record, why, failed, ran=True):
    """The record once its switch failed (``failed``) or was interrupted
    (``ran``: after `current` moved to it): an update is failed; a
    rollback's target gets its state back."""
    if not ran:
        why = "interrupted before it was switched to (power cut, reboot or crash)"
    if record.switch and record.switch.kind == "rollback":
        note = {"time": now(), "reason": why}
        state = record.switch.prior_state or ACTIVE
        return record._replace(state=state, **({"rollback_failed": note} if failed else {"rollback_interrupted": note}))
    return record._replace(state=FAILED, reason=why, failed=precise_now())
