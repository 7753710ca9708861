"""The release's converge run as the agent sees it (robotfleet/pull/robot/converge.py
is the other side): starting it in a release's own tree and venv, reading its
one JSON line, and what that line says of the run."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

TIMEOUT = 5 * 3600
NOT_HERE, TAMPERED = 3, 4  # an image helper's exit statuses (robotfleet.role Role.image_helper)


def classify(said: dict, version: int) -> tuple[str, str]:
    """The converge run's outcome, applied, rolled-back or failed, and why (one line)."""
    if said.get("error"):
        return "failed", f"release {version}: {said['error']}"
    results = said.get("results") or []
    rolled = [r for r in results if r.get("outcome") == "rolled-back"]
    if rolled:
        return "rolled-back", f"release {version}: {rolled[0].get('why')}"
    bad = [r for r in results if not r.get("ok")]
    if said.get("exit") or bad:
        why = bad[0]["why"] if bad else "; ".join(said.get("errors") or []) or f"pyinfra exited {said.get('exit')}"
        return "failed", f"release {version}: {why}"
    missing = said.get("missing") or []
    if missing:
        return "failed", f"release {version}: {missing[0]['role']}: {missing[0]['why']}"
    return "applied", f"release {version} applied"


def run(python: Path, code: Path, arguments: list[str]) -> dict:
    """Run the release's converge module in its own tree; its JSON line."""
    env = dict(os.environ, PYTHONPATH=str(code), PYTHONDONTWRITEBYTECODE="1")
    try:
        done = subprocess.run(
            [str(python), "-m", "robotfleet.commands.converge", *arguments],
            cwd=code,
            env=env,
            capture_output=True,
            text=True,
            timeout=TIMEOUT,
        )
    except (OSError, subprocess.TimeoutExpired) as error:
        return {"error": f"converge: {error}"}
    said = last_json(done.stdout)
    if said is None:
        tail = [line for line in done.stderr.splitlines() if line.strip()]
        return {"error": f"converge said nothing ({tail[-1] if tail else f'exit {done.returncode}'})"}
    return said


def last_json(text: str) -> dict | None:
    """The last line of ``text`` that is a JSON object: what a converge, or
    a role's switch, answers after whatever else it printed."""
    for line in reversed(text.splitlines()):
        if line.startswith("{"):
            try:
                found = json.loads(line)
            except ValueError:
                continue
            if isinstance(found, dict):
                return found
    return None


def status(state: Path, robot: str, fleet: str | None) -> dict:
    """The roles' status as the code the agent runs now reads it (no new
    release): converge status's answer ({"row", "missing", "watch"});
    ``fleet``: the fleet file's path in that code (None: the defaults)."""
    code = state / "code" / "current"
    return run(
        state / "venv" / "bin" / "python",
        code,
        ["status", "--robot", robot] + (["--fleet", str(code / fleet)] if fleet else []),
    )


def converge(state: Path, record, robot: str, code: Path, venv: Path, action: str, deployment: str, *more) -> dict:
    """One converge action (run, prepare) of the release ``record``
    in its tree and venv, in a work directory of its own that goes
    afterwards; a run's pyinfra log becomes ``last-run.log``."""
    work = state / "runs" / deployment
    release_file = work.with_suffix(".release.json")
    work.mkdir(parents=True, exist_ok=True, mode=0o700)
    release_file.write_bytes(record.to_bytes())
    fleet = str(code / record.fleet["path"])
    try:
        return run(
            venv / "bin" / "python",
            code,
            [action, "--robot", robot, "--fleet", fleet, "--record", str(release_file), "--deployment", deployment]
            + ["--work", str(work), *more],
        )
    finally:
        release_file.unlink(missing_ok=True)
        if action == "run" and (work / "pyinfra.log").exists():
            os.replace(work / "pyinfra.log", state / "last-run.log")
        shutil.rmtree(work, ignore_errors=True)


def switch(argv: list[str]) -> dict:
    """A prepared switch, its role's own command (robotfleet.role
    SwitchPart): the last JSON line it printed, {"ok", "outcome",
    "message", ...}; {} when it said nothing readable."""
    try:
        done = subprocess.run(
            [str(a) for a in argv], capture_output=True, text=True, timeout=TIMEOUT, stdin=subprocess.DEVNULL
        )
    except (OSError, subprocess.TimeoutExpired):
        return {}
    return last_json(done.stdout) or {}


def helper(argv, *args: str) -> tuple[int | None, str]:
    """A role's image helper (agent.json's ``image_helper``) run with
    ``args``: its exit status (None: no helper on this robot) and its last
    line on stderr."""
    if not argv:
        return None, "no role on this robot declares an image helper"
    try:
        done = subprocess.run([*argv, *args], capture_output=True, text=True, timeout=TIMEOUT, stdin=subprocess.DEVNULL)
    except (OSError, subprocess.TimeoutExpired) as error:
        return None, f"image helper: {error}"
    lines = [line.strip() for line in done.stderr.splitlines() if line.strip()]
    return done.returncode, lines[-1] if lines else f"exit {done.returncode}"
