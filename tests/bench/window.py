"""How long a robot runs no payload, and how fast a broken release is
replaced, read from Docker's own clocks on the robot.  Pure parsing here;
the benchmarks (tests/bench/fleet.py, releases.py) run the commands.

- The update window: from the old container's last moment running (its
  FinishedAt) to the new one's first (its StartedAt).  Compose removes the
  old container right after it stops, so its FinishedAt is read from what
  Docker takes it from: containerd's `/tasks/exit` event (``exited_at``,
  the same nanoseconds), recorded on the robot by `ctr events` while the
  update runs.  Docker's `die` event comes some 0.1 s later (after the
  daemon's clean-up), which is why it is not used.
- A broken release: Docker's verdict (the container's exit, from the same
  recorder, or its `health_status: unhealthy` event) and the broken
  container's first start (`/tasks/start`) -> the old release's StartedAt.
"""

from __future__ import annotations

import calendar
import json
import re
import shlex
import time

PROJECT = "robot-payload"
RECORDER = "/run/bench-ctr-events"  # on the robot: <RECORDER>.txt and .pid

# `ctr events` lines: "2026-11-25 08:42:26.750996863 +0000 UTC moby /tasks/exit {...}"
CTR_LINE = re.compile(r"^\S+ \S+ \S+ \S+ (?P<namespace>\S+) (?P<topic>/\S+) (?P<data>\{.*\})\s*$")


def start_recorder() -> str:
    """A robot-side shell command: record containerd's events of Docker's
    namespace in the background until stop_recorder()."""
    return (
        f"sudo sh -c 'rm -f {RECORDER}.txt; nohup ctr -n moby events > {RECORDER}.txt 2>&1 < /dev/null &"
        f" echo $! > {RECORDER}.pid'; sleep 0.3"
    )


def stop_recorder() -> str:
    """Stop the recorder and print what it recorded."""
    return (
        f"sudo sh -c 'kill $(cat {RECORDER}.pid) 2>/dev/null; sleep 0.1; cat {RECORDER}.txt;"
        f" rm -f {RECORDER}.txt {RECORDER}.pid'"
    )


def containers_command(project: str = PROJECT) -> str:
    """Robot-side: one JSON object per line for each container of the
    payload's project: id, service, version label, StartedAt, FinishedAt, running."""
    fmt = (
        '{"id": "{{.Id}}", "service": "{{index .Config.Labels "com.docker.compose.service"}}", '
        '"version": "{{index .Config.Labels "org.opencontainers.image.version"}}", '
        '"started": "{{.State.StartedAt}}", "finished": "{{.State.FinishedAt}}", "running": {{.State.Running}}}'
    )
    return (
        f"ids=$(sudo docker ps -aq --no-trunc --filter label=com.docker.compose.project={project});"
        f' [ -z "$ids" ] || sudo docker inspect --format {shlex.quote(fmt)} $ids'
    )


def health_events_command(since: float, project: str = PROJECT) -> str:
    """Robot-side: Docker's health verdicts of the project's containers since ``since``."""
    return (
        f"sudo docker events --since {since:.3f} --until $(date +%s.%N) --filter type=container"
        f" --filter label=com.docker.compose.project={project} --filter event=health_status"
        " --format '{{.TimeNano}} {{.ID}} {{.Action}}'"
    )


def docker_time(text: str) -> float | None:
    """Docker's RFC 3339 time with nanoseconds as seconds since the epoch
    (None for Docker's zero time, "0001-01-01T00:00:00Z")."""
    if not text or text.startswith("0001-"):
        return None
    match = re.match(r"^(\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d)(?:\.(\d+))?(Z|[+-]\d\d:\d\d)$", text.strip())
    if not match:
        raise ValueError(f"not a Docker time: {text!r}")
    seconds = calendar.timegm(time.strptime(match.group(1), "%Y-%m-%dT%H:%M:%S"))
    fraction = float("0." + match.group(2)) if match.group(2) else 0.0
    zone = match.group(3)
    if zone != "Z":
        sign = 1 if zone[0] == "+" else -1
        seconds -= sign * (int(zone[1:3]) * 3600 + int(zone[4:6]) * 60)
    return seconds + fraction


def containers(text: str) -> list[dict]:
    """containers_command()'s output, times as seconds."""
    found = []
    for line in text.splitlines():
        line = line.strip()
        if line.startswith("{"):
            data = json.loads(line)
            data["started"], data["finished"] = docker_time(data["started"]), docker_time(data["finished"])
            found.append(data)
    return found


def ctr_events(text: str) -> list[dict]:
    """The `/tasks/start` and `/tasks/exit` of containers' own processes
    (not of `docker exec`s, such as health probes) in stop_recorder()'s
    output: {topic, id, time}; an exit's time is its ``exited_at``, a
    start's is when containerd sent it."""
    found = []
    for line in text.splitlines():
        match = CTR_LINE.match(line)
        if not match or match.group("topic") not in ("/tasks/start", "/tasks/exit"):
            continue
        data = json.loads(match.group("data"))
        cid = data.get("container_id")
        if match.group("topic") == "/tasks/exit":
            if data.get("id") != cid:  # an exec's process, not the container's
                continue
            at = data.get("exited_at") or {}
            when = int(at.get("seconds", 0)) + int(at.get("nanos", 0)) / 1e9
        else:
            date, clock = line.split()[:2]
            when = docker_time(f"{date}T{clock}Z")
        found.append({"topic": match.group("topic"), "id": cid, "time": when})
    return found


def health_events(text: str) -> list[dict]:
    """health_events_command()'s output: {time, id, status}."""
    found = []
    for line in text.splitlines():
        parts = line.split(None, 2)
        if len(parts) == 3 and parts[2].startswith("health_status"):
            found.append({"time": int(parts[0]) / 1e9, "id": parts[1], "status": parts[2].split(":", 1)[1].strip()})
    return found


def update_window(before: list[dict], after: list[dict], events: list[dict]) -> float | None:
    """Seconds without the payload in an update: for each service, the old
    container's exit -> the new one's StartedAt; the longest of them (None
    when no service was replaced)."""
    exits = {e["id"]: e["time"] for e in events if e["topic"] == "/tasks/exit"}
    windows = []
    for old in before:
        if not old.get("running") or old["id"] not in exits:
            continue
        new = [c for c in after if c["service"] == old["service"] and c["id"] != old["id"] and c.get("started")]
        if new:
            windows.append(max(c["started"] for c in new) - exits[old["id"]])
    return max(windows) if windows else None


def broken_release(before: list[dict], after: list[dict], events: list[dict], health: list[dict]) -> dict | None:
    """A release that failed and was rolled back: the broken containers are
    those started during the run that are gone afterwards.  Returns the
    seconds from the broken release's first start, and from Docker's
    verdict (its first exit, or its `unhealthy` status, whichever came
    first), to the old release running again (its StartedAt), with which
    verdict it was; None when no broken container ran."""
    kept = {c["id"] for c in before} | {c["id"] for c in after}
    starts = [e for e in events if e["topic"] == "/tasks/start" and e["id"] not in kept]
    if not starts or not after:
        return None
    broken = {e["id"] for e in starts}
    first = min(e["time"] for e in starts)
    verdicts = [(e["time"], "exit") for e in events if e["topic"] == "/tasks/exit" and e["id"] in broken]
    verdicts += [
        (h["time"], "unhealthy")
        for h in health
        if h["status"] == "unhealthy" and any(b.startswith(h["id"]) or h["id"].startswith(b) for b in broken)
    ]
    back = [c["started"] for c in after if c.get("running") and c.get("started") and c["started"] > first]
    if not back or not verdicts:
        return None
    verdict_at, kind = min(verdicts)
    return {
        "verdict": kind,
        "first_start_to_old_running": min(back) - first,
        "verdict_to_old_running": min(back) - verdict_at,
    }


class Watch:
    """What one robot's payload did between begin() and end() (or inside a
    ``with``): ``sh(command)`` runs a shell command on the robot and returns
    its output."""

    def __init__(self, sh):
        self.sh = sh

    def begin(self) -> "Watch":
        self.before = containers(self.sh(containers_command()))
        self.since = float(self.sh("date +%s.%N").strip())
        self.sh(start_recorder())
        return self

    def end(self) -> "Watch":
        self.events = ctr_events(self.sh(stop_recorder()))
        self.after = containers(self.sh(containers_command()))
        self.health = health_events(self.sh(health_events_command(self.since)))
        return self

    def __enter__(self):
        return self.begin()

    def __exit__(self, *exc):
        self.end()
        return False

    def window(self) -> float | None:
        return update_window(self.before, self.after, self.events)

    def broken(self) -> dict | None:
        return broken_release(self.before, self.after, self.events, self.health)


def describe_healthcheck(check: dict | None) -> str:
    """An image's Config.Healthcheck (`docker image inspect`) as one line."""
    if not check or not check.get("Test") or check["Test"][0] == "NONE":
        return "no HEALTHCHECK"
    seconds = {k: (check.get(k) or 0) / 1e9 for k in ("Interval", "Timeout", "StartPeriod")}
    return (
        f"HEALTHCHECK interval {seconds['Interval']:g} s, timeout {seconds['Timeout']:g} s, "
        f"start period {seconds['StartPeriod']:g} s, retries {check.get('Retries') or 3}"
    )


def healthcheck_command(tag: str) -> str:
    """Robot-side: the HEALTHCHECK of the lab's ros/payload:<tag> as JSON."""
    return (
        f"ref=$(sudo docker images --format '{{{{.Repository}}}}:{{{{.Tag}}}}' | grep -m1 '/ros/payload:{tag}$');"
        " sudo docker image inspect -f '{{json .Config.Healthcheck}}' \"$ref\""
    )


def health_settings(sh, tag: str, fleet_text: str) -> str:
    """The image's HEALTHCHECK and the fleet's payload_health_timeout, as one line."""
    out = sh(healthcheck_command(tag)).strip().splitlines()
    check = json.loads(out[-1]) if out and out[-1].startswith(("{", "null")) else None
    timeout = next(
        (
            line.split(":")[1].strip()
            for line in fleet_text.splitlines()
            if line.strip().startswith("payload_health_timeout:")
        ),
        "120 (default)",
    )
    return describe_healthcheck(check) + f"; payload_health_timeout {timeout} s"


# The two kinds of broken release the benchmarks deploy: (tag, payload_command)
BROKEN = {
    "exits at once": ("1.0", "[/bin/sh, -c, 'exit 3']"),
    "runs, never healthy": ("1.2-broken", None),
}
