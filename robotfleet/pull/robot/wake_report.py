"""A wake's report (robotfleet/pull/protocol/reports.py) and its journal
line: built from what the wake found, with the robot's keys, what the wake
cost and, while the robot holds a bundle's enrollment key, the proof it
signs (robotfleet/pull/robot/enrollment_proof.py); pushed to
refs/reports/<robot> when it says something new or its heartbeat is due
(onto a mounted medium when the remote is out of reach)."""

from __future__ import annotations

import glob
import hashlib
import json
import os
import re
import time
from pathlib import Path
from urllib.parse import urlsplit

import robotfleet
from robotfleet.pull.protocol import enrollment, reports
from robotfleet.pull.robot import enrollment_proof
from robotfleet.pull.robot.journal import cpu_seconds
from robotfleet.pull.robot.transport import TransportError


def build(wake, outcome) -> dict:
    """The report of ``wake`` (robotfleet/pull/robot/agent.py's Wake), ended by ``outcome``."""
    record = wake.record
    cost = wake.remote.cost.as_dict()
    cost["cpu"] = cpu_seconds()
    hosts, key = host_keys(), public_key(wake.config.etc("id_ed25519.pub"))
    try:
        proof = enrollment_proof.proof(wake.config.etc("enroll_ed25519"), wake.config.robot, key, hosts, wake.state)
    except enrollment.ProofError as error:
        print(f"robot-pull: no enrollment proof in the report: {error}", flush=True)
        proof = None
    return reports.build(
        wake.config.robot,
        wake.clock(),
        outcome.result,
        reason=outcome.reason,
        refusal=outcome.refusal,
        seen=reports.version_of(record) if record else wake.state.get("seen"),
        applied=wake.state.get("applied"),
        attempted=wake.state.get("attempted"),
        wave=outcome.wave,
        status=wake.status,
        host_keys=hosts,
        key=key,
        config=wake.config,
        check=cost,
        agent=agent_version(),
        status_time=wake.status_time,
        enrollment=proof,
    )


def send(wake, report: dict) -> str:
    """Push the report when it says something new or the heartbeat is
    due; what happened, for the journal line."""
    substance = hashlib.sha256(json.dumps(reports.substance(report), sort_keys=True).encode()).hexdigest()
    last = wake.state.get("reported") or {}
    age = time.time() - last.get("at", 0)
    if last.get("substance") == substance and 0 <= age < wake.config.heartbeat:
        said = "report unchanged"
    elif wake.key_refused_by and same_ssh_server(wake.key_refused_by, wake.remote.report_url):
        # the same keys would be refused again, and each refused login counts against this
        # address on an OpenSSH >= 9.8 server (PerSourcePenalties, docs/guides/pull.md)
        said = "report not sent (the fleet remote refused this robot's key in this check)"
    else:
        try:
            wake.remote.push_report(wake.config.robot, reports.to_bytes(report))
            wake.state["reported"] = {"substance": substance, "at": time.time()}
            said = "report sent"
        except TransportError as error:
            said = f"report not sent ({error})"
            if wake.medium is not None:
                from robotfleet.pull.robot import media

                said += "; " + media.write_report(wake.medium, wake.config.robot, reports.to_bytes(report))
    if wake.remote.retire_enrollment_key():  # the server took this robot's own key in this wake
        said += "; the enrollment key is retired (the remote knows this robot's own key)"
    return said


def same_ssh_server(one: str, other: str) -> bool:
    """Two remotes reached by one SSH login: the same user, host and port
    (pure).  Both forms pull_remote takes (robotfleet/fleet/pull_mode.py):
    ssh://user@host[:port]/path and git's scp-like user@host:path."""
    login = ssh_login(one)
    return login is not None and login == ssh_login(other)


def ssh_login(remote: str) -> tuple[str, str, int] | None:
    """(user, host, port) of an SSH remote, None for any other (pure)."""
    scp_like = re.match(r"([^@/:]+)@(\[[^\]/]+\]|[^:/\[]+):(?!//)", remote)
    if scp_like:
        return scp_like[1], scp_like[2].strip("[]").lower(), 22
    try:
        parts = urlsplit(remote)
        if parts.scheme == "ssh" and parts.hostname:
            return parts.username or "", parts.hostname, parts.port or 22
    except ValueError:
        pass
    return None


def host_keys() -> list[str]:
    keys = []
    for path in sorted(glob.glob("/etc/ssh/ssh_host_*_key.pub")):
        key = public_key(path)
        if key:
            keys.append(key)
    return keys


def public_key(path: str) -> str | None:
    try:
        return " ".join(Path(path).read_text().split()[:2]) or None
    except OSError:
        return None


def agent_version() -> str:
    code = os.path.realpath(robotfleet.CHECKOUT)
    return f"{robotfleet.__version__} (tree {os.path.basename(code)[:12]})"
