"""payloadctl's command line, and the lock every change runs under."""

import argparse
import os
import socket
import sys
import time

from . import agent_images, durable, hold, logs, recovery, results, status
from .apply import apply, prepare, switch
from .lifecycle import Life, Refused
from .lock import Busy, Lock, describe
from .releases import Releases
from .rollback import rollback
from .spec import Run, load_request
from .system import Failure, Refusal, log


def locked(releases, lock_timeout, owner, work, run_):
    """Run ``work(life, lock)`` holding the robot's one apply/rollback lock
    (or as part of the run whose lock token ``run_`` carries), after
    undoing a switch a power cut left unverified; every outcome is recorded
    as this run's structured result (the deploy reads it, not our stderr)."""
    root, action = releases.root, owner["action"]

    def failed(outcome, why):
        return results.finish(root, action, outcome, "payload: {}".format(why), run_, reason=str(why))

    lock = Lock(root, lock_timeout, owner)
    try:
        lock.acquire(on_wait=lambda holder: log("payload: {}; waiting".format(describe(holder))), token=run_.lock_token)
    except Busy as busy:
        return failed(results.REFUSED, busy)
    try:
        life = Life(releases)
        recovered = life.recover()
        if recovered:
            log(recovered)
        return work(life, lock)
    except (Refusal, Refused) as error:
        return failed(results.REFUSED, error)
    except Failure as error:
        return failed(results.FAILED, error)
    except OSError as error:
        return failed(results.FAILED, "cannot write on this robot: {}".format(error))
    except Exception as error:
        return failed(results.FAILED, "internal error in payloadctl ({}): {!r}".format(action, error))
    finally:
        lock.release()


def read_token(path):
    """A lock token from a file only root can have written (payloadctl hold)."""
    if not path:
        return None
    with open(path) as handle:
        return handle.read().strip() or None


def _request(args, action):
    """(spec, run) of a request file; a result refusing it when it cannot be read."""
    try:
        spec, run_ = load_request(args.request)
    except (OSError, ValueError, KeyError, TypeError) as error:
        root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(args.request))))  # <dir>/runs/<id>/
        why = "this payloadctl cannot read the deploy's request ({}); deploy again".format(error)
        run_ = Run(args.run_id, "unknown", False, False, socket.gethostname())
        return None, results.finish(root, action, results.REFUSED, "payload: " + why, run_, reason=why)
    return (
        spec,
        run_._replace(run_id=args.run_id or run_.run_id, restart=getattr(args, "restart", False) or run_.restart),
    ), None


def _requested(args, action, work):
    """``work(spec, run, life, lock)`` for the request file, under the lock."""
    found, refused = _request(args, action)
    if found is None:
        return refused
    spec, run_ = found
    releases = Releases(spec.dir)
    durable.make_private_dir(releases.dir)
    owner = {"by": run_.by, "action": action, "run_id": run_.run_id}
    return locked(releases, spec.apply_lock_timeout, owner, lambda life, lock: work(spec, run_, life, lock), run_)


def cmd_apply(args):
    return _requested(args, "apply", apply)


def cmd_prepare(args):
    return _requested(args, "prepare", lambda spec, run_, life, lock: prepare(spec, run_, life))


def cmd_switch(args):
    releases = Releases(args.dir)
    run_ = Run(args.run_id, args.by or "unknown", False, False, socket.gethostname(), args.deployment)
    spec = releases.spec(args.release) if args.release in releases.ids() else None
    lock_timeout = spec.apply_lock_timeout if spec else 0
    owner = {"by": run_.by, "action": "switch", "run_id": run_.run_id}
    return locked(releases, lock_timeout, owner, lambda life, lock: switch(args.release, run_, life, lock), run_)


def cmd_rollback(args):
    releases = Releases(args.dir)
    run_ = Run(
        args.run_id,
        args.by or "unknown",
        args.force,
        False,
        socket.gethostname(),
        lock_token=read_token(args.lock_token_file),
    )
    spec = releases.spec(releases.pointer("current")) or releases.spec(releases.pointer("previous"))
    lock_timeout = spec.apply_lock_timeout if spec else 0  # releases of an older payloadctl: do not wait
    owner = {"by": run_.by, "action": "rollback", "run_id": run_.run_id}
    return locked(releases, lock_timeout, owner, lambda life, lock: rollback(run_, life, lock), run_)


def cmd_hold(args):
    return hold.hold(args.dir, args.token_file, args.command, args.timeout, args.by)


def cmd_result(args):
    return results.report(args.dir, args.name, args.run_id)


def cmd_status(args):
    return status.show(args.dir, args.name, args.lock_file)


def cmd_start(args):
    return recovery.start(Releases(args.dir), args.name, reload=args.reload)


def cmd_prune_logs(args):
    return logs.main(args.dir, args.max_mb, args.suffix)


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
    p = sub.add_parser("prepare", help="all of an apply before the switch: the release written and checked")
    p.add_argument("request", help="as apply's")
    p.add_argument("--run-id")
    p.set_defaults(func=cmd_prepare)
    p = sub.add_parser("switch", help="the rest of an apply, for a release prepare made")
    p.add_argument("--dir", required=True)
    p.add_argument("--release", required=True, help="the id prepare's result names (its target)")
    p.add_argument("--run-id")
    p.add_argument("--by")
    p.add_argument("--deployment", help="the deployment named in the result")
    p.set_defaults(func=cmd_switch)
    p = sub.add_parser("rollback", help="go back to the previous release, with its own spec")
    p.add_argument("--dir", required=True)
    p.add_argument("--run-id")
    p.add_argument("--by")
    p.add_argument("--force", action="store_true", help="although the update lock is held")
    p.add_argument("--lock-token-file", help="the apply lock's token of the run this rollback is part of")
    p.set_defaults(func=cmd_rollback)
    p = sub.add_parser("hold", help="hold the apply lock while COMMAND runs; requests with its token join it")
    p.add_argument("--dir", required=True)
    p.add_argument("--token-file", required=True, help="where the token is written (0600) for COMMAND")
    p.add_argument(
        "--timeout",
        type=int,
        help="seconds to wait for another holder (default: the release's payload_apply_lock_timeout, else 300)",
    )
    p.add_argument("--by", default="payloadctl hold", help="who holds it, as waiters are told")
    p.add_argument("command", nargs="+", help="the command to run (after --)")
    p.set_defaults(func=cmd_hold)
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
    p = sub.add_parser("prune-logs", help="remove the oldest ROS logs until the rest fit in --max-mb")
    p.add_argument("--dir", required=True)
    p.add_argument("--max-mb", type=int, required=True)
    p.add_argument("--suffix", help="only files whose names end so (bags: .bag), nothing else touched")
    p.set_defaults(func=cmd_prune_logs)
    p = sub.add_parser("image-pull", help="the pull agent's: pull images by their digest, unless here")
    p.add_argument("--docker-dir", required=True, help="where Docker keeps images (its free disk is checked)")
    p.add_argument("--min-free-mb", type=int, required=True)
    p.add_argument("refs", nargs="+", metavar="REPOSITORY@DIGEST")
    p.set_defaults(func=lambda a: agent_images.command(agent_images.pull, a.refs, a.docker_dir, a.min_free_mb))
    p = sub.add_parser("image-load", help="the pull agent's: load an image of a release on media, checked")
    p.add_argument("ref", help="the image as the release names it")
    p.add_argument("digest", help="the digest the release pins")
    p.add_argument("image", help="the image id the release binds")
    p.add_argument("archive", nargs="?", help="the archive to load (none: only say whether it is here)")
    p.set_defaults(func=lambda a: agent_images.command(agent_images.load, a.ref, a.digest, a.image, a.archive))
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
