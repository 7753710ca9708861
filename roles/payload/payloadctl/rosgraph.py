"""The release judged by its ROS graph (ros_health): the probe
(rosgraph_probe.py, stdlib only) run inside the project's roscore
container, so it reads the graph from the project's own network in host and
bridge networking alike.

What the graph must show travels in the release's compose document, under
the top-level extension key ``x-ros-health`` (compose ignores ``x-`` keys):
it is part of what identifies the release, so a changed ros_health is a new
release, and a rollback or `status` judges each release by its own."""

import json
import pkgutil

from .system import run

KEY = "x-ros-health"
SERVICE = "roscore"  # the service the probe runs in (the fleet check refuses ros_health without it)
MIN_WITHIN = 10  # seconds the gate gives the graph at least, however long the containers took


def expected(compose):
    """What the release's graph must show, or None when it declares nothing."""
    found = (compose or {}).get(KEY)
    return found if isinstance(found, dict) and found else None


def roscore_container(name):
    proc = run(
        [
            "docker",
            "ps",
            "-q",
            "--filter",
            "label=com.docker.compose.project=" + name,
            "--filter",
            "label=com.docker.compose.service=" + SERVICE,
        ],
        check=False,
        timeout=60,
    )
    found = proc.stdout.split()
    return found[0] if found else None


def probe_source():
    return pkgutil.get_data(__package__, "rosgraph_probe.py").decode()


def not_run(why):
    return {"ok": False, "problems": [why], "rates": {}, "nodes": []}


def probe(name, wanted, within):
    """The probe's report ({"ok", "problems", "rates", "nodes"}), trying
    for up to ``within`` seconds; a probe that cannot run is one problem."""
    cid = roscore_container(name)
    if cid is None:
        return not_run("no running {} container to read the graph from".format(SERVICE))
    request = json.dumps(dict(wanted, within=within), sort_keys=True)
    proc = run(
        ["docker", "exec", "-i", cid, "python3", "-", request],
        check=False,
        input_text=probe_source(),
        timeout=within + 120,
    )
    for line in reversed((proc.stdout or "").splitlines()):
        if line.startswith("{"):
            try:
                report = json.loads(line)
            except ValueError:
                break
            if isinstance(report.get("problems"), list):
                return report
    said = ((proc.stderr or "") + (proc.stdout or "")).strip().splitlines()
    return not_run(
        "the graph probe could not run in {} (its image needs python3): {}".format(
            SERVICE, said[-1][-200:] if said else "exit {}".format(proc.returncode)
        )
    )


def verdict(report):
    """One line: "ok" or the problems."""
    return "ok" if report["ok"] else "; ".join(report["problems"])


def gate(spec, within):
    """(True, "") when the release's graph is what ros_health declares (or
    it declares nothing); (False, "ROS graph: <problems>") otherwise."""
    wanted = expected(spec.compose)
    if wanted is None:
        return True, ""
    report = probe(spec.name, wanted, max(MIN_WITHIN, int(within)))
    return report["ok"], "" if report["ok"] else "ROS graph: " + verdict(report)


def now_verdict(releases, name, rid):
    """The graph's verdict for `status` now, one look (None: release ``rid`` declares no ros_health)."""
    spec = releases.spec(rid) if rid else None
    wanted = expected(spec.compose) if spec and spec.autostart else None
    if wanted is None:
        return None
    return verdict(probe(name, wanted, 0))
