"""payloadctl's command line, and the lock every change runs under."""

import argparse
import os
import socket
import sys
import time

from . import durable, recovery, results, status
from .apply import apply
from .lock import Busy, Lock, describe
from .releases import Releases
from .rollback import rollback
from .spec import Run, load_request
from .system import Failure, log


def locked(releases, lock_timeout, owner, work):
    """Run ``work`` holding the robot's one apply/rollback lock, after undoing
    a switch a power cut left unverified; every outcome is recorded as this
    run's result (the deploy reads the result, not our stderr)."""
    root, run_id = releases.root, owner["run_id"]
    lock = Lock(root, lock_timeout, owner)
    try:
        lock.acquire(on_wait=lambda holder: log("payload: {}; waiting".format(describe(holder))))
    except Busy as busy:
        return results.finish(root, False, "payload: {}".format(busy), run_id=run_id)
    try:
        recovered = recovery.recover(releases)
        if recovered:
            log(recovered)
        return work(lock)
    except Failure as error:
        return results.finish(root, False, "payload: {}".format(error), run_id=run_id)
    except OSError as error:
        return results.finish(root, False, "payload: cannot write on this robot: {}".format(error), run_id=run_id)
    except Exception as error:
        return results.finish(root, False, "payload: internal error in payloadctl ({}): {!r}".format(
            owner["action"], error), run_id=run_id)
    finally:
        lock.release()


def cmd_apply(args):
    try:
        spec, run_ = load_request(args.request)
    except (OSError, ValueError, KeyError, TypeError) as error:
        root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(args.request))))  # <dir>/runs/<id>/
        return results.finish(root, False, "payload: this payloadctl cannot read the deploy's request ({}); "
                              "deploy again".format(error), run_id=args.run_id)
    run_ = run_._replace(run_id=args.run_id or run_.run_id, restart=args.restart or run_.restart)
    releases = Releases(spec.dir)
    durable.make_private_dir(releases.dir)
    owner = {"by": run_.by, "action": "apply", "run_id": run_.run_id}
    return locked(releases, spec.apply_lock_timeout, owner, lambda lock: apply(spec, run_, releases, lock))


def cmd_rollback(args):
    releases = Releases(args.dir)
    run_ = Run(args.run_id, args.by or "unknown", args.force, False, socket.gethostname())
    spec = releases.spec(releases.pointer("current")) or releases.spec(releases.pointer("previous"))
    lock_timeout = spec.apply_lock_timeout if spec else 0  # releases of an older payloadctl: do not wait
    owner = {"by": run_.by, "action": "rollback", "run_id": run_.run_id}
    return locked(releases, lock_timeout, owner, lambda lock: rollback(run_, releases, lock))


def cmd_result(args):
    return results.report(args.dir, args.name, args.run_id)


def cmd_status(args):
    return status.show(args.dir, args.name, args.lock_file)


def cmd_start(args):
    return recovery.start(Releases(args.dir), args.name, reload=args.reload)


def cmd_wait_devices(args):
    deadline = time.time() + args.timeout
    while True:
        missing = [d for d in args.devices if not os.path.exists(d)]
        if not missing:
            return 0
        if time.time() >= deadline:
            print("payload: sensors missing after {} s: {}".format(args.timeout, " ".join(missing)), file=sys.stderr)
            return 1
        time.sleep(1)


def parser():
    top = argparse.ArgumentParser(prog="payloadctl", description="Releases of this robot's payload.")
    sub = top.add_subparsers(dest="command")
    p = sub.add_parser("apply", help="make the release a request file asks for")
    p.add_argument("request", help='JSON: {"spec": {...}, "run": {"by": ..., "force": ...}}')
    p.add_argument("--restart", action="store_true", help="restart the unit (it changed)")
    p.add_argument("--run-id")
    p.set_defaults(func=cmd_apply)
    p = sub.add_parser("rollback", help="go back to the previous release, with its own spec")
    p.add_argument("--dir", required=True)
    p.add_argument("--run-id")
    p.add_argument("--by")
    p.add_argument("--force", action="store_true", help="although the update lock is held")
    p.set_defaults(func=cmd_rollback)
    p = sub.add_parser("result", help="print a run's result and exit with it")
    p.add_argument("--dir", required=True)
    p.add_argument("--name", required=True)
    p.add_argument("--run-id")
    p.set_defaults(func=cmd_result)
    p = sub.add_parser("status", help="what runs, as one JSON line")
    p.add_argument("--dir", required=True)
    p.add_argument("--name", required=True)
    p.add_argument("--lock-file")
    p.set_defaults(func=cmd_status)
    p = sub.add_parser("start", help="the unit's start at boot: undo an unverified switch, run current")
    p.add_argument("--dir", required=True)
    p.add_argument("--name", required=True)
    p.add_argument("--reload", action="store_true", help="the unit's reload: run current, decide nothing")
    p.set_defaults(func=cmd_start)
    p = sub.add_parser("wait-devices", help="wait for the sensors' device links")
    p.add_argument("--timeout", type=int, default=30)
    p.add_argument("devices", nargs="+")
    p.set_defaults(func=cmd_wait_devices)
    return top


def main(argv=None):
    args = parser().parse_args(argv)
    if not getattr(args, "func", None):
        parser().print_help()
        return 2
    return args.func(args)
