"""The unit's start (boot, and reload): decide which release runs, then
bring it up; undo a switch a power cut left unverified.

At boot the recovery holds the apply lock from its decision to the end of
its `compose up`, so a deploy arriving meanwhile waits instead of cutting
that `compose up` short (which left a half-recreated container and made the
deploy's own start fail on its name).  The containers of a release not yet
verified get restart policy `no`, so after a power cut Docker does not bring
them back before the recovery has decided; a verified release's containers
get their compose file's policy."""

import json
import os

from . import health
from .lifecycle import SWITCHING, Life
from .lock import Busy, Lock, describe
from .system import Failure, log, run


def recover(releases):
    """Undo a switch that never finished (power cut or crash between the
    switch and its verdict), finish one whose way back was cut short: a line
    for the log when `current` went back, else None (lifecycle.Life.recover)."""
    return Life(releases).recover()


def up(releases, name):
    """`compose up` of `current`, after clearing what an interrupted one
    left; an unverified release without restart policies until verified."""
    path = os.path.join(releases.root, "current", "compose.yaml")
    cleared = health.clear_leftovers(name)
    if cleared:
        log("payload: removed what an interrupted compose up left: {}".format(", ".join(cleared)))
    compose = ["docker", "compose", "-p", name, "-f", path, "up", "-d", "--remove-orphans"]
    unverified = Life(releases).state(releases.pointer("current")) == SWITCHING
    if unverified:
        run(compose + ["--no-start"])
        health.set_restart_policies(name, "no")
    run(compose)
    if not unverified:
        health.set_restart_policies(name, health.restart_policies(compose_doc(path)))
    return 0


def compose_doc(path):
    with open(path) as handle:
        return json.loads(handle.read().split("\n", 1)[1])  # the comment line, then JSON


def start(releases, name, reload=False):
    """The unit's ExecStart (boot) and ExecReload.  A deploy that holds the
    apply lock and started the unit decides alone; otherwise the start takes
    the lock (a deploy then waits for it) for its decision and its compose
    up.  A deploy that holds the lock without having started the unit has
    undone any unverified switch already (cli.locked): current runs as it is."""
    lock = Lock(releases.root, 0, {"by": "boot" if not reload else "reload", "action": "start"})
    try:
        lock.acquire(blocking=False)
    except Busy:
        holder = lock.holder() or {}
        if not holder.get("starts_unit"):
            log("payload: {}; starting current as it is".format(describe(holder)))
        return _up(releases, name)
    except OSError as error:
        log("payload: cannot take the apply lock ({}); starting current as it is".format(error))
        return _up(releases, name)
    try:
        if not reload:
            recovered = recover(releases)
            if recovered:
                log(recovered)
        return _up(releases, name)
    finally:
        lock.release()


def _up(releases, name):
    try:
        return up(releases, name)
    except Failure as error:
        log("payload: {}".format(error))
        return 1
