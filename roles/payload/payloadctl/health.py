"""Is the release running well: its containers' states, the health gate,
and the checks other roles add (the GPU check)."""

import json
import pkgutil
import re
import time

from . import platforms
from .events import Events
from .system import run

LOOK = 2.0  # seconds between looks while Docker's events wake the wait (a safety net only)


def project_containers(name):
    proc = run(["docker", "ps", "-aq", "--filter", "label=com.docker.compose.project=" + name], check=False, timeout=60)
    return proc.stdout.split()


def described(data):
    """One `docker inspect` record as the health gate reads it."""
    state = data["State"]
    health = state.get("Health") or {}
    log_tail = ""
    if health.get("Log"):
        log_tail = (health["Log"][-1].get("Output") or "").strip()[-200:]
    return {
        "name": data["Name"].lstrip("/"),
        "image": data["Config"]["Image"],
        "image_id": data["Image"],
        "status": state["Status"],
        "health": health.get("Status"),
        "health_log": log_tail,
        "restarts": data.get("RestartCount", 0),
        "started": state.get("StartedAt"),
        "exit_code": state.get("ExitCode"),
        "error": state.get("Error") or "",
    }


def container_state(cid):
    found = inspect_containers([cid])
    return described(found[0]) if found else None


def states(name):
    """Every container of the project, read with one `docker inspect`."""
    return [described(c) for c in inspect_containers(project_containers(name))]


def inspect_containers(ids):
    """`docker inspect` of ``ids`` in one call ([] when there are none)."""
    if not ids:
        return []
    proc = run(["docker", "inspect"] + list(ids), check=False)
    try:
        return json.loads(proc.stdout or "[]")
    except ValueError:
        return []


def verdict(found, baseline):
    """One look at the containers: ("ok" | "wait" | "fail" | "stable", why).

    A container that has exited, is restarting or restarted since the first
    look, or that Docker's HEALTHCHECK calls unhealthy, fails the release at
    once: waiting out the health timeout would only keep a broken payload."""
    if not found:
        return "wait", "no container started"
    outcome, why = "ok", ""
    for s in found:
        baseline.setdefault(s["name"], s["restarts"])
        if s["status"] in ("exited", "dead"):
            return "fail", "{} exited with code {}".format(s["name"], s["exit_code"])
        if s["status"] == "restarting" or s["restarts"] > baseline[s["name"]]:
            return "fail", "{} is crash-looping (restarted {} times, last exit code {})".format(
                s["name"], s["restarts"], s["exit_code"]
            )
        if s["health"] == "unhealthy":
            return "fail", "{} is unhealthy: {}".format(s["name"], s["health_log"] or "health check failed")
        if s["status"] != "running":
            outcome, why = "wait", "{} is {}".format(s["name"], s["status"])
        elif s["health"] == "starting":
            outcome, why = "wait", "{} health check still starting".format(s["name"])
        elif s["health"] is None and outcome == "ok":
            outcome = "stable"
    return outcome, why


def exec_format_failure(found, output_of):
    """The failure of a container whose program the kernel could not
    execute at all (ENOEXEC: built for another architecture), named as
    such; None when no container says so.  ``output_of(name)``: its log."""
    for s in found:
        if s["status"] in ("running",) and not s["restarts"]:
            continue
        if platforms.exec_format_error(s.get("error")) or platforms.exec_format_error(output_of(s["name"])):
            return (
                "{} cannot run: exec format error: its program is not built for this robot's architecture "
                "(image {})".format(s["name"], s["image"])
            )
    return None


def container_output(name):
    proc = run(["docker", "logs", "--tail", "20", name], check=False, timeout=60)
    return (proc.stdout or "") + (proc.stderr or "")


def wait_healthy(name, timeout, stable_seconds, since=None):
    """(True, "") once every container is healthy (HEALTHCHECK) or has run
    without restarting for stable_seconds; (False, why) at the first sign of
    failure or when `timeout` runs out.  Between looks it waits for Docker's
    next event about the project (events.py; ``since``: replayed from then,
    the moment before the release was brought up), so Docker's own verdict
    (an exit, `unhealthy`) is acted on as soon as Docker gives it."""
    deadline = time.time() + timeout
    baseline = {}
    stable_since = None
    why = "no container started"
    with Events(name, since) as events:
        while True:
            found = states(name)
            outcome, reason = verdict(found, baseline)
            if outcome == "fail":
                return False, exec_format_failure(found, container_output) or reason
            if outcome == "ok":
                return True, ""
            pause = LOOK
            if outcome == "stable":
                stable_since = stable_since or time.time()
                if time.time() - stable_since >= stable_seconds:
                    return True, ""
                why = "waiting for {} s without restarts".format(stable_seconds)
                pause = min(pause, stable_since + stable_seconds - time.time())
            else:
                stable_since = None
                why = reason
            if time.time() >= deadline:
                return False, "not healthy after {} s (payload_health_timeout): {}".format(timeout, why)
            events.wait(min(pause, deadline - time.time()))


def containers_up(name):
    """The payload really runs: containers exist, all running, none unhealthy."""
    found = states(name)
    return bool(found) and all(s["status"] == "running" and s["health"] != "unhealthy" for s in found)


# --- the project's containers, before and after compose up -------------------

LEFTOVER = re.compile(r"^[0-9a-f]{12}_")  # compose renames a container it recreates to <id>_<name> first
RUNNING = ("running", "restarting", "paused")  # `docker ps` states of a container Docker counts as running


def clear_leftovers(name):
    """Remove what an interrupted `compose up` left: containers renamed
    <id>_<name> during a recreate, and stopped ones that would hold the
    project's names (compose creates them afresh).  Returns their names.
    One `docker ps` reads them (this runs before every compose up)."""
    removed = []
    listed = run(
        [
            "docker",
            "ps",
            "-a",
            "--no-trunc",
            "--filter",
            "label=com.docker.compose.project=" + name,
            "--format",
            "{{.ID}} {{.Names}} {{.State}}",
        ],
        check=False,
        timeout=60,
    )
    for line in listed.stdout.splitlines():
        cid, cname, state = (line.split() + ["", "", ""])[:3]
        if cid and (LEFTOVER.match(cname) or state not in RUNNING):
            if run(["docker", "rm", "-f", cid], check=False, timeout=120).returncode == 0:
                removed.append(cname)
    return removed


def set_restart_policies(name, policies):
    """Give each container of the project its service's policy (``policies``:
    service -> policy, or one policy for all), without recreating it."""
    for c in inspect_containers(project_containers(name)):
        service = (c["Config"].get("Labels") or {}).get("com.docker.compose.service")
        wanted = policies.get(service, "no") if isinstance(policies, dict) else policies
        if ((c["HostConfig"].get("RestartPolicy") or {}).get("Name") or "no") != wanted:
            run(["docker", "update", "--restart", wanted, c["Id"]], check=False, timeout=60)


def run_checks(name, checks):
    """(True, "") when every check's command succeeds in every container of
    the project; (False, why) for the first that does not."""
    for check in checks or ():
        if "graph" in check:
            ok, why = graph_healthy(name, check["graph"])
            if not ok:
                return False, "{}: {}".format(check["failure"], why)
            continue
        command = list(check["command"])
        for cid in project_containers(name):
            proc = run(["docker", "exec", cid] + command, check=False)
            if proc.returncode != 0:
                who = (container_state(cid) or {}).get("name", cid)
                said = (proc.stderr or proc.stdout).strip()[-200:] or "exit {}".format(proc.returncode)
                return False, "{} {} ({} failed: {})".format(who, check["failure"], " ".join(command), said)
    return True, ""


def graph_healthy(name, wanted):
    """(True, "") when the ROS graph is what ``wanted`` declares (ros_health),
    read from inside it: graphprobe.py run by the python3 of the project's
    roscore container; (False, its lines joined) when not."""
    proc = run(
        ["docker", "ps", "-q", "--filter", "label=com.docker.compose.project=" + name]
        + ["--filter", "label=com.docker.compose.service=" + wanted["service"]],
        check=False,
        timeout=60,
    )
    found = proc.stdout.split()
    if not found:
        return False, "no running {} container to read the ROS graph from".format(wanted["service"])
    return probe_graph(found[0], wanted)


def probe_graph(container, wanted):
    script = pkgutil.get_data(__package__, "graphprobe.py").decode()
    wait = float(wanted.get("wait") or 0)
    proc = run(
        ["docker", "exec", "-i", container, "python3", "-", json.dumps(wanted)],
        check=False,
        input_text=script,
        timeout=wait + 120,
    )
    if proc.returncode == 0:
        return True, ""
    lines = (
        proc.stdout.strip().splitlines()
        or (proc.stderr or "exit {}".format(proc.returncode)).strip()[-200:].splitlines()
    )
    return False, "; ".join(lines)
