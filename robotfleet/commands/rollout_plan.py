"""Rollout planning, computable without a host: waves, the failure budget,
and the rollout state kept on the operator's machine between runs.

A robot's *target* is what the roles' rollout parts ask of it (the payload:
every image of its compose project); it is *done* when its status row shows
that.  robotfleet/commands/rollout.py runs the deploy wave by wave with these
functions deciding what happens next.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import os
import time

# A count and the failure budget are the same rule in push and pull rollouts.
from robotfleet import atomicfile
from robotfleet.pull.protocol.waves import Count, allowed_failures, parse_count  # noqa: F401 - rollout.py reads them here


def build_waves(hosts: list[str], flagged: list[str], canary: Count, batch: Count) -> list[list[str]]:
    """Canaries first (hosts with rollout_canary, else the first ``canary``
    hosts), then batches of ``batch`` hosts in inventory order.  Percentages
    are of the whole selection, rounded up (at least one robot per wave)."""
    total = len(hosts)
    if flagged:
        canaries = [h for h in hosts if h in set(flagged)]
    else:
        canaries = hosts[: canary.of(total, round_up=True)]
    rest = [h for h in hosts if h not in set(canaries)]
    size = max(1, batch.of(total, round_up=True)) if batch.value else max(1, len(rest))
    waves = [canaries] if canaries else []
    waves += [rest[i : i + size] for i in range(0, len(rest), size)]
    return waves


def fleet_key(inventory: str, selection: list[str], targets: dict[str, str]) -> str:
    """The rollout's identity: same inventory, same robots, same targets ->
    same state file, so rerunning the same command resumes it."""
    blob = json.dumps({"inventory": os.path.abspath(inventory), "hosts": selection, "targets": targets}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def state_dir(root: str = ".") -> str:
    """Where rollout states live: $ROBOT_ROLLOUT_DIR, else .rollout/ here."""
    return os.environ.get("ROBOT_ROLLOUT_DIR") or os.path.join(root, ".rollout")


def state_path(key: str, root: str = ".") -> str:
    return os.path.join(state_dir(root), f"{key}.json")


def new_state(key: str, inventory: str, waves: list[list[str]], targets: dict[str, str], allowed: int) -> dict:
    return {
        "key": key,
        "inventory": inventory,
        "waves": waves,
        "targets": targets,
        "allowed_failures": allowed,
        "wave": 0,
        "status": "running",
        "done": [],
        "failed": {},
        "skipped": {},
        "attempts": 0,
    }


def pending(state: dict) -> list[str]:
    done = set(state["done"])
    return [h for wave in state["waves"] for h in wave if h not in done]


def record_wave(state: dict, index: int, done: list[str], failed: dict[str, str], skipped: dict[str, str]) -> dict:
    """The state after wave ``index``: a pure update, then the verdict in
    state['status']: 'running' (go on), 'stopped' (budget spent), 'complete'."""
    state = json.loads(json.dumps(state))
    state["wave"] = index
    state["done"] = sorted(set(state["done"]) | set(done))
    for host in done:
        state["failed"].pop(host, None)
        state["skipped"].pop(host, None)
    for host in failed:  # a robot has one outcome, its latest: the summary's counts add up
        state["skipped"].pop(host, None)
    for host in skipped:
        state["failed"].pop(host, None)
    state["failed"].update(failed)
    state["skipped"].update(skipped)
    state["run_failures"] = state.get("run_failures", 0) + len(failed)
    if state["run_failures"] > state["allowed_failures"]:
        state["status"] = "stopped"
    elif index + 1 >= len(state["waves"]):
        state["status"] = "complete" if not pending(state) else "incomplete"
    else:
        state["status"] = "running"
    return state


def start_run(state: dict) -> dict:
    """A rerun of the same command: the budget is per run, robots still not on
    the target (failed, skipped or never reached) are tried again."""
    state = json.loads(json.dumps(state))
    state["attempts"] = state.get("attempts", 0) + 1
    state["run_failures"] = 0
    state["status"] = "running"
    return state


def save_state(path: str, state: dict) -> None:
    """Write atomically (robotfleet/atomicfile.py)."""
    atomicfile.write(path, json.dumps(state, indent=2, sort_keys=True) + "\n", make_parents=True)


class RolloutBusy(Exception):
    pass


def lock_path(inventory: str, sources: list[str], root: str = ".") -> str:
    """The fleet's rollout lock: one per inventory file and the fleet it read
    (the fleet file or directory), whatever the rollout's flags (--limit,
    --data, the waves), so that two rollouts never update one fleet at once."""
    blob = json.dumps({"inventory": os.path.abspath(inventory), "fleet": sorted(sources)})
    return os.path.join(state_dir(root), f"fleet-{hashlib.sha256(blob.encode()).hexdigest()[:16]}.lock")


@contextlib.contextmanager
def held(path: str):
    """The fleet's rollout lock ``path`` (lock_path), held for a whole run: a
    second rollout of the same fleet refuses (it would update the same
    robots, and lose the first one's state)."""
    os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
    fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, 0o600)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            note = os.pread(fd, 200, 0).decode(errors="replace").strip()
            raise RolloutBusy(
                f"another rollout of this fleet is running ({note or 'unknown process'}); wait for it, or stop it"
            ) from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"pid {os.getpid()} since {time.strftime('%Y-%m-%dT%H:%M:%S')}".encode(), 0)
        yield
    finally:
        os.close(fd)


def load_state(path: str) -> dict | None:
    try:
        with open(path) as handle:
            return json.load(handle)
    except FileNotFoundError:
        return None


def latest_state(root: str = ".") -> dict | None:
    """The most recently written rollout state under ``root`` (for the status table)."""
    directory = state_dir(root)
    try:
        files = [os.path.join(directory, f) for f in os.listdir(directory) if f.endswith(".json")]
    except FileNotFoundError:
        return None
    if not files:
        return None
    try:
        return load_state(max(files, key=os.path.getmtime))
    except ValueError:
        return None


OUTCOMES = ("done", "failed", "skipped", "pending")


def outcome(state: dict, host: str) -> str:
    """Where ``host`` stands: done, failed, skipped (unreachable) or pending
    (not reached yet, or a rerun has not come to it): one of these each."""
    if host in state["done"]:
        return "done"
    if host in state["failed"]:
        return "failed"
    if host in state["skipped"]:
        return "skipped"
    return "pending"


def reason(state: dict, host: str) -> str | None:
    return state["failed"].get(host) or state["skipped"].get(host) if outcome(state, host) != "done" else None


def host_state(state: dict | None, host: str) -> str | None:
    """One cell for the status table: where ``host`` stands in the rollout."""
    if not state:
        return None
    wave = next((i for i, w in enumerate(state["waves"]) if host in w), None)
    if wave is None:
        return None
    return f"wave {wave + 1}/{len(state['waves'])} {outcome(state, host)}"


def summary(state: dict) -> str:
    """One line: which rollout, which wave, how many robots stand where (the
    counts add up to the robots of the rollout), which are pending."""
    robots = [h for wave in state["waves"] for h in wave]
    counts = {name: 0 for name in OUTCOMES}
    for host in robots:
        counts[outcome(state, host)] += 1
    left = [h for h in robots if outcome(state, h) == "pending"]
    waves = len(state["waves"])
    return (
        f"rollout {state['key']}: {state['status']} after wave {min(state['wave'] + 1, waves)}/{waves}; "
        + ", ".join(f"{counts[name]} {name}" for name in OUTCOMES)
        + f" of {len(robots)} robot(s)"
        + f"; pending: {', '.join(left) or 'none'}"
    )
