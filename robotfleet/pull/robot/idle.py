"""An idle check that costs the exchange and little more: the first thing
robot-pull.service's process does (robotfleet/pull/agent.py), before it
imports the agent.

A full wake (robotfleet/pull/robot/agent.py) that found nothing to do ends
by writing ``<state>/idle.json`` (``remember``): what the next wake would
read if nothing changed (the configuration's text, the code it runs, what
lstat says of every file its decision and its report read, the releases
branch's commit and what the last verification read), until when no time
limit of it is reached (the verified metadata's first expiry, the roles'
status and the report's heartbeat), and its journal line's words.  The next
wake (``check``) that finds all of it still so, and the remote's branch
still at that commit (one probe, robotfleet/pull/robot/probe.py), is that
wake again: it moves the trusted time as trust_state.recall does, prints the
same line and ends.  Over HTTPS the probe is one request from this process,
which imports socket, ssl, json and a few small modules (no dataclasses,
pathlib, subprocess, TUF, pyinfra, YAML, Jinja2); over SSH it is the full
wake's own ``git ls-remote`` with its ssh (robotfleet/pull/robot/remote_git.py),
subprocess the only one of those it imports (tests/integration/test_pull_idle_memo.py
holds both).  Anything else (one file changed, known_hosts and the robot's
keys among them; a limit reached; the probe unanswered, failed or another
commit; a remote neither HTTPS nor SSH, a medium, a derived robot name, an
enrollment key held over SSH) and the full wake runs, as before; the
probe's answer (or its failure) is handed to it, not asked again.
"""

from __future__ import annotations

import fcntl
import json
import os
import sys
import time

import robotfleet
from robotfleet import atomicfile
from robotfleet.pull.protocol.path_signatures import watched
from robotfleet.pull.robot import journal, probe, trust_fingerprint

MEMO = "idle.json"
FORMAT = 3  # 3: the keepalives the probe is bounded by
STATE_FILE = "agent-state.json"  # robotfleet/pull/robot/agent_state.py's
_TIME = "%Y-%m-%dT%H:%M:%SZ"  # robotfleet/pull/protocol/record.py's, in UTC


def files_read(state_dir: str, etc_dir: str) -> list[str]:
    """What an idle wake's decision and report read besides the network:
    the agent's state, the last verification, the code it runs, the
    robot's keys (its own, an enrollment key's, the host's), the CA and
    the git server's pinned host keys."""
    host_keys = "/etc/ssh"
    try:
        names = sorted(n for n in os.listdir(host_keys) if n.startswith("ssh_host_") and n.endswith("_key.pub"))
    except OSError:
        names = []
    return [
        *(f"{state_dir}/{name}" for name in (STATE_FILE, "verified.json", "verified.release.json", "code/current")),
        *(
            f"{etc_dir}/{name}"
            for name in (
                "id_ed25519",
                "id_ed25519.pub",
                "enroll_ed25519",
                "enroll_ed25519.pub",
                "remote-ca.pem",
                "known_hosts",
            )
        ),
        host_keys,
        *(f"{host_keys}/{name}" for name in names),
    ]


def forget(state_dir) -> None:
    """No memo: a next check runs the full wake.  One that cannot be removed
    (not a file) cannot be read either, so that holds too."""
    try:
        os.unlink(os.path.join(state_dir, MEMO))
    except OSError:
        pass


def remember(wake, outcome, config_text: str, said: str) -> None:
    """After a full wake (robotfleet/pull/robot/agent.py's Wake) that ended
    in ``outcome``, its report ``said``: the memo a next idle wake may stand
    on, when this one was idle and nothing of it depends on more than the
    memo holds; else none.  The memo only saves work: one that cannot be
    written (a full disk, a state file it cannot read) costs the next check
    its shortcut, never this wake."""
    try:
        _remember(wake, outcome, config_text, said)
    except (OSError, ValueError, KeyError, TypeError):
        forget(str(wake.state_dir))


def _remember(wake, outcome, config_text: str, said: str) -> None:
    from robotfleet.pull.protocol import record as records
    from robotfleet.pull.robot import remote_git

    config, state, record = wake.config, wake.state, wake.record
    over = "https" if config.remote.startswith("https://") else "ssh" if remote_git.is_ssh(config.remote) else None
    state_dir = str(wake.state_dir)
    forget(state_dir)
    status, reported = state.get("status") or {}, state.get("reported") or {}
    if (
        record is None
        or (outcome.result, outcome.reason) != ("up-to-date", None)
        or record.version > wake.applied_version()
        or said not in ("report unchanged", "report sent")
        or wake.medium is not None
        or config.media_dir
        or config.name_rule is not None
        or over is None
        # over SSH the full wake retires an enrollment key once the server takes the robot's own
        or (over == "ssh" and os.path.lexists(f"{config.etc_dir}/enroll_ed25519"))
        or status.get("row") is None
        or not isinstance(status.get("watch"), dict)
        or status.get("code") != os.path.realpath(f"{state_dir}/code/current")
        or not isinstance(reported.get("at"), (int, float))
    ):
        return
    fetched = probe.read_memo(wake.remote.repo, config.remote, config.branch)
    try:
        with open(f"{state_dir}/verified.json") as file:
            verified = json.load(file)
        with open(f"{state_dir}/trust.json") as file:
            trust = json.load(file)
        expires = records.parse_time(verified["expires"], "expires").timestamp()
    except (OSError, ValueError, KeyError, TypeError, records.RecordError):
        return
    target = probe.target(config.remote) if over == "https" else None
    if fetched is None or (over == "https" and target is None) or verified.get("fingerprint") is None:
        return
    if verified.get("source") != str(wake.remote.repo):
        return
    heartbeat = config.heartbeat
    memo = {
        "format": FORMAT,
        "config": config_text,
        "code": os.path.realpath(robotfleet.CHECKOUT_DIR),
        "state_dir": state_dir,
        "etc_dir": config.etc_dir,
        "disks": [config.state_dir, config.docker_dir],
        "min_free_mb": config.min_free_mb,
        "url": config.remote,
        "over": over,
        "target": target,
        "branch": config.branch,
        "timeout": config.fetch_timeout,
        "keepalive": list(wake.remote.keepalive),
        "silent": wake.remote.silence,
        "fetched": fetched,
        "verified": {k: verified.get(k) for k in ("source", "reads", "fingerprint")},
        "trust": {"version": trust.get("version"), "release": trust.get("release")},
        "expires": verified["expires"],
        "since": max(float(status.get("at") or 0), float(reported["at"])),
        "until": min(expires, float(status.get("at") or 0) + heartbeat, float(reported["at"]) + heartbeat),
        "watch": status["watch"],
        "files": watched(files_read(state_dir, config.etc_dir)),
        "result": "up-to-date",
        "seen": record.version,
        "said": "report unchanged",  # this wake's report (sent, or not new) is the next one's
    }
    atomicfile.write(os.path.join(state_dir, MEMO), json.dumps(memo, sort_keys=True) + "\n")


def _config_path(argv: list[str]) -> str | None:
    if len(argv) == 2 and argv[0] == "--config":
        return argv[1]
    if len(argv) == 1 and argv[0].startswith("--config="):
        return argv[0].split("=", 1)[1]
    return None


def check(argv: list[str]) -> int | None:
    """One wake as robot-pull.service runs it (``argv``: its arguments):
    0 when it was idle and said so, None when the full wake is to run."""
    started = time.monotonic()
    path = _config_path(argv)
    try:
        with open(path or "") as file:
            text = file.read()
        state_dir = json.loads(text)["state_dir"]
        with open(os.path.join(state_dir, MEMO)) as file:
            memo = json.load(file)
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if not isinstance(memo, dict) or memo.get("format") != FORMAT or memo.get("config") != text:
        return None
    try:
        lock = open(os.path.join(state_dir, "agent.lock"), "a")
    except OSError:
        return None
    with lock:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            return None  # another check runs: the full wake says so
        try:
            said = _idle(memo, time.time())
        except (OSError, ValueError, KeyError, TypeError):
            said = None
        if said is None:
            return None
    print(journal.journal_line(said, memo["said"], time.monotonic() - started), flush=True)
    return 0


def _idle(memo: dict, now: float) -> dict | None:
    """The idle wake's report's words, when ``memo`` still holds at ``now``; None."""
    state_dir, etc_dir = memo["state_dir"], memo["etc_dir"]
    if not (memo["since"] <= now < memo["until"]) or memo["code"] != os.path.realpath(robotfleet.CHECKOUT_DIR):
        return None
    if watched(files_read(state_dir, etc_dir)) != memo["files"] or watched(memo["watch"]) != memo["watch"]:
        return None
    for disk in memo["disks"]:  # as Wake.check_disk: too little free, and the full wake says so
        if os.path.isdir(disk):
            fs = os.statvfs(disk)
            if fs.f_bavail * fs.f_frsize // (1 << 20) < memo["min_free_mb"]:
                return None
    now_text = time.strftime(_TIME, time.gmtime(now))
    with open(f"{state_dir}/trust.json") as file:
        trust = json.load(file)
    if (
        not _is_time(trust.get("time"))
        or {"version": trust.get("version"), "release": trust.get("release")} != memo["trust"]
        or not trust["time"] <= now_text < memo["expires"]
    ):
        return None
    repo, verified = f"{state_dir}/releases", memo["verified"]
    fetched = probe.read_memo(repo, memo["url"], memo["branch"])
    if fetched != memo["fetched"] or not os.path.isdir(f"{repo}/.git"):
        return None
    started = time.monotonic()
    if memo["over"] == "ssh":  # as the full wake asks (transport.Remote._probe): ssh, git and subprocess only here
        from robotfleet.pull.robot import remote_git

        keepalive = tuple(memo["keepalive"])
        answer = remote_git.ls_remote(repo, memo["url"], memo["branch"], etc_dir, memo["timeout"], keepalive)
    else:
        ca = f"{etc_dir}/remote-ca.pem"
        ca = ca if os.path.exists(ca) else None
        answer = probe.ask(memo["target"], memo["branch"], fetched, ca, memo["timeout"], memo["silent"])
    if answer is None or answer.commit != fetched["commit"]:
        probe.give(fetched, answer, time.monotonic() - started)
        return None
    if answer.validators != fetched.get("validators", {}):  # as transport.Remote.fetch_releases
        probe.write_memo(repo, memo["url"], memo["branch"], fetched["commit"], fetched["kind"], answer.validators)
    if trust_fingerprint.fingerprint(repo, verified["reads"]) != verified["fingerprint"]:
        probe.give(fetched, answer, time.monotonic() - started)
        return None
    if trust["time"] < now_text:  # the trusted time moves, as trust_state.recall moves it
        atomicfile.write(
            f"{state_dir}/trust.json", trust_fingerprint.trust_bytes(now_text, trust["version"], trust["release"])
        )
    return {
        "result": memo["result"],
        "seen": {"version": memo["seen"]},
        "check": {"cpu": journal.cpu_seconds(), "sent": answer.sent, "received": answer.received, "requests": 1},
    }


def _is_time(text) -> bool:
    """``text`` is a time as trust.json holds it ("2026-11-25T10:00:00Z"; without _strptime's import)."""
    if not isinstance(text, str) or len(text) != 20 or text[4::3][:6] != "--T::Z":
        return False
    digits = text[:4] + text[5:7] + text[8:10] + text[11:13] + text[14:16] + text[17:19]
    return digits.isascii() and digits.isdigit()


def leave() -> None:
    """Before the full wake, when python was started with -S (the bench and
    the tests, to leave ``site`` out of what they measure; robot-pull.service
    does not: an earlier release's agent has no such step): the
    site-packages ``site`` would have added at start (python-tuf and the rest)."""
    if sys.flags.no_site:
        import site

        site.main()
