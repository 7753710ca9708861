"""Every run's outcome, recorded where the deploy reads it: runs/<id>/
result.json (and last-result.json).  The deploy reads the result, not
payloadctl's output, so a dropped SSH link loses nothing."""

import os
import shutil
import sys

from . import durable
from .releases import RUNS
from .system import log, now

RESULT = "last-result.json"
# Control characters (an escape sequence in a healthcheck's output, a label,
# docker's stderr) are shown, not obeyed, on the operator's terminal.
_SHOWN = {i: "\\x{:02x}".format(i) for i in list(range(0x20)) + [0x7F] + list(range(0x80, 0xA0))}
_SHOWN.update({0x2028: "\\u2028", 0x2029: "\\u2029"})


def one_line(text):
    return text.translate(_SHOWN)


def run_dir(root, run_id):
    return os.path.join(root, RUNS, run_id)


def finish(root, ok, message, release=None, run_id=None):
    message = one_line(message)
    result = {"ok": ok, "message": message, "release": release, "time": now(), "run_id": run_id}
    log(message)
    if run_id:
        durable.make_private_dir(run_dir(root, run_id))
        durable.write_json(os.path.join(run_dir(root, run_id), "result.json"), result)
    durable.write_json(os.path.join(root, RESULT), result)
    return 0 if ok else 1


def report(root, name, run_id):
    """Print this run's result and exit with it; a missing result is a failure."""
    path = os.path.join(run_dir(root, run_id), "result.json") if run_id else os.path.join(root, RESULT)
    result = durable.read_json(path)
    if not result or (run_id and result.get("run_id") != run_id):
        print(
            "payload: payloadctl recorded no result for this run ({}): disk full? see journalctl -u '{}-*-{}' on the robot".format(
                run_id, name, run_id),
            file=sys.stderr,
        )
        code = 1
    else:
        stream = sys.stdout if result["ok"] else sys.stderr
        print(one_line(str(result["message"])), file=stream)
        code = 0 if result["ok"] else 1
    if run_id:
        shutil.rmtree(run_dir(root, run_id), ignore_errors=True)
    return code
