"""Is the release running well: its containers' states, the health gate,
and the checks other roles add (the GPU check)."""

import json
import re
import subprocess
import time

from . import platforms
from .system import Failure, run

POLL = 0.5  # seconds between health looks: a crash is seen within about this


def project_containers(name):
    proc = run(["docker", "ps", "-aq", "--filter", "label=com.docker.compose.project=" + name], check=False, timeout=60)
    return proc.stdout.split()


def container_state(cid):
    proc = run(["docker", "inspect", cid], check=False, timeout=60)
    if proc.returncode != 0:
        return None
    data = json.loads(proc.stdout)[0]
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


def states(name):
    return [s for s in (container_state(c) for c in project_containers(name)) if s]


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
                s["name"], s["restarts"], s["exit_code"])
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
            return ("{} cannot run: exec format error: its program is not built for this robot's architecture "
                    "(image {})".format(s["name"], s["image"]))
    return None


def container_output(name):
    proc = run(["docker", "logs", "--tail", "20", name], check=False, timeout=60)
    return (proc.stdout or "") + (proc.stderr or "")


def wait_healthy(name, timeout, stable_seconds):
    """(True, "") once every container is healthy (HEALTHCHECK) or has run
    without restarting for stable_seconds; (False, why) at the first sign of
    failure or when `timeout` runs out."""
    deadline = time.time() + timeout
    baseline = {}
    stable_since = None
    why = "no container started"
    while True:
        found = states(name)
        outcome, reason = verdict(found, baseline)
        if outcome == "fail":
            return False, exec_format_failure(found, container_output) or reason
        if outcome == "ok":
            return True, ""
        if outcome == "stable":
            stable_since = stable_since or time.time()
            if time.time() - stable_since >= stable_seconds:
                return True, ""
            why = "waiting for {} s without restarts".format(stable_seconds)
        else:
            stable_since = None
            why = reason
        if time.time() >= deadline:
            return False, "not healthy after {} s (payload_health_timeout): {}".format(timeout, why)
        time.sleep(POLL)


def containers_up(name):
    """The payload really runs: containers exist, all running, none unhealthy."""
    found = states(name)
    return bool(found) and all(s["status"] == "running" and s["health"] != "unhealthy" for s in found)


def unit_active(unit):
    return run(["systemctl", "is-active", "--quiet", unit], check=False, timeout=60).returncode == 0


UNIT_BUSY = ("activating", "deactivating", "reloading")
UNIT_SETTLE = 120  # seconds to wait for a start in progress (the boot's) to finish


def wait_unit_settled(unit):
    """A start in progress (the boot's compose up) is never cut short by a
    restart: that leaves a half-recreated container behind."""
    deadline = time.time() + UNIT_SETTLE
    while time.time() < deadline:
        state = run(["systemctl", "show", "-p", "ActiveState", "--value", unit], check=False, timeout=60).stdout.strip()
        if state not in UNIT_BUSY:
            return
        time.sleep(POLL)


def start_release(name, restart, lock=None):
    """Run `current` through the payload's unit.  ``lock`` (the apply lock
    this run holds) notes that the unit's start is ours, so the start runs
    without waiting for the lock (recovery.start)."""
    unit = name + ".service"
    wait_unit_settled(unit)
    if lock is not None:
        lock.note(starts_unit=True)
    try:
        if restart or not unit_active(unit):
            run(["systemctl", "restart", unit], timeout=600)
        else:
            run(["systemctl", "reload", unit], timeout=600)
    finally:
        if lock is not None:
            lock.note(starts_unit=False)


# --- the project's containers, before and after compose up -------------------

LEFTOVER = re.compile(r"^[0-9a-f]{12}_")  # compose renames a container it recreates to <id>_<name> first


def clear_leftovers(name):
    """Remove what an interrupted `compose up` left: containers renamed
    <id>_<name> during a recreate, and stopped ones that would hold the
    project's names (compose creates them afresh).  Returns their names."""
    removed = []
    for c in inspect_containers(project_containers(name)):
        cname = c["Name"].lstrip("/")
        if LEFTOVER.match(cname) or not c["State"].get("Running"):
            if run(["docker", "rm", "-f", c["Id"]], check=False, timeout=120).returncode == 0:
                removed.append(cname)
    return removed


def restart_policies(compose_doc):
    """service -> the restart policy its compose file asks for."""
    return {name: str(s.get("restart") or "no") for name, s in compose_doc["services"].items()}


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
        command = list(check["command"])
        for cid in project_containers(name):
            proc = run(["docker", "exec", cid] + command, check=False)
            if proc.returncode != 0:
                who = (container_state(cid) or {}).get("name", cid)
                said = (proc.stderr or proc.stdout).strip()[-200:] or "exit {}".format(proc.returncode)
                return False, "{} {} ({} failed: {})".format(who, check["failure"], " ".join(command), said)
    return True, ""


def start_and_check(spec, restart, lock=None):
    """Bring `current` up and wait for it: (healthy?, why not)."""
    try:
        start_release(spec.name, restart, lock)
        return wait_healthy(spec.name, spec.health_timeout, spec.stable_seconds)
    except Failure as error:
        return False, str(error)
    except subprocess.TimeoutExpired as error:
        return False, "{} did not finish within {} s".format(" ".join(error.cmd[:3]), error.timeout)
