"""Every run's outcome as one structured result: written where the deploy
reads it (runs/<id>/result.json, and last-result.json for status and the
pull agent) and printed as one JSON line on stdout.  Lines for people go to
stderr; programs read the result, never them.

The result, format 1 (docs/reference/payloadctl.md):

    {"payloadctl": 1, "ok": bool, "outcome": one of OUTCOMES,
     "action": "apply" | "rollback" | "prepare" | "switch",
     "release": what `current` is after the run, "previous": what `previous` is,
     "target": the release this run made or switched to (None: none),
     "reason": why it is not ok (one line; None when ok), "message": the line for people,
     "taken_over": [{"name", "project", "image", "why"}], "run_id", "deployment", "host",
     "time": "YYYY-MM-DDTHH:MM:SSZ"}
"""

import json
import os
import shutil
import sys

from . import durable
from .releases import RUNS, Releases
from .system import log, now

FORMAT = 1
RESULT = "last-result.json"
APPLIED, ALREADY_CURRENT, STAGED = "applied", "already-current", "staged"
ROLLED_BACK, FAILED, REFUSED = "rolled-back", "failed", "refused"
PREPARED = "prepared"  # `payloadctl prepare`: written and checked, `switch` runs it
OUTCOMES = (APPLIED, ALREADY_CURRENT, STAGED, PREPARED, ROLLED_BACK, FAILED, REFUSED)
OK = (APPLIED, ALREADY_CURRENT, STAGED, PREPARED)
# Control characters (an escape sequence in a healthcheck's output, a label,
# docker's stderr) are shown, not obeyed, on the operator's terminal.
_SHOWN = {i: "\\x{:02x}".format(i) for i in list(range(0x20)) + [0x7F] + list(range(0x80, 0xA0))}
_SHOWN.update({0x2028: "\\u2028", 0x2029: "\\u2029"})


def one_line(text):
    return text.translate(_SHOWN)


def run_dir(root, run_id):
    return os.path.join(root, RUNS, run_id)


def document(root, action, outcome, message, run=None, target=None, reason=None, taken_over=()):
    """The result of this run, with the pointers as the run left them."""
    if outcome not in OUTCOMES:
        raise ValueError("unknown outcome {!r}".format(outcome))
    releases = Releases(root)
    return {
        "payloadctl": FORMAT,
        "ok": outcome in OK,
        "outcome": outcome,
        "action": action,
        "release": releases.pointer("current"),
        "previous": releases.pointer("previous"),
        "target": target,
        "reason": one_line(reason) if reason and outcome not in OK else None,
        "message": one_line(message),
        "taken_over": [{k: c.get(k) for k in ("name", "project", "image", "why")} for c in taken_over or ()],
        "run_id": run.run_id if run else None,
        "deployment": run.deployment if run else None,
        "host": run.host if run else None,
        "time": now(),
    }


def finish(root, action, outcome, message, run=None, target=None, reason=None, taken_over=()):
    """Record this run's result, say it, and return the exit status."""
    result = document(root, action, outcome, message, run, target, reason, taken_over)
    log(result["message"])
    run_id = result["run_id"]
    try:
        if run_id:
            durable.make_private_dir(run_dir(root, run_id))
            durable.write_json(os.path.join(run_dir(root, run_id), "result.json"), result)
        durable.write_json(os.path.join(root, RESULT), result)
    finally:
        print(json.dumps(result, sort_keys=True), flush=True)
    return 0 if result["ok"] else 1


def upgraded(result):
    """A result as format 1 (one an older payloadctl wrote has ok and message only)."""
    if result.get("payloadctl") == FORMAT:
        return result
    ok = bool(result.get("ok"))
    return {
        "payloadctl": FORMAT,
        "ok": ok,
        "outcome": APPLIED if ok else FAILED,
        "action": "apply",
        "release": result.get("release"),
        "previous": None,
        "target": None,
        "reason": None if ok else one_line(str(result.get("message"))),
        "message": one_line(str(result.get("message"))),
        "taken_over": [],
        "run_id": result.get("run_id"),
        "deployment": None,
        "host": None,
        "time": result.get("time"),
    }


def last(root):
    """The last run's result (format 1), or None before the first."""
    result = durable.read_json(os.path.join(root, RESULT))
    return upgraded(result) if result else None


def report(root, name, run_id):
    """Print this run's result (one JSON line on stdout, its line for people
    on stderr) and exit with it; a missing result is a failure."""
    path = os.path.join(run_dir(root, run_id), "result.json") if run_id else os.path.join(root, RESULT)
    result = durable.read_json(path)
    if not result or (run_id and result.get("run_id") != run_id):
        message = (
            "payload: payloadctl recorded no result for this run ({}): disk full? see journalctl -u '{}-*-{}' "
            "on the robot".format(run_id, name, run_id)
        )
        result = document(root, "apply", FAILED, message, reason=message[len("payload: ") :])
        result["run_id"] = run_id
    else:
        result = upgraded(result)
    print(one_line(str(result["message"])), file=sys.stderr, flush=True)
    print(json.dumps(result, sort_keys=True), flush=True)
    if run_id:
        shutil.rmtree(run_dir(root, run_id), ignore_errors=True)
    return 0 if result["ok"] else 1
