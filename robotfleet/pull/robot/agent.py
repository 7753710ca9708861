"""The pull agent: one wake of robot-pull.service on a robot.

    python -m robotfleet.pull.agent [--config /etc/robot-pull/agent.json]

1. One wake at a time (a lock in the state directory); enough free disk first.
2. Fetch the releases branch (robotfleet/pull/robot/transport.py) and verify it
   with TUF (robotfleet/pull/robot/verify.py): a refusal (unsigned, unknown key,
   tampered, a rollback, expired) leaves everything as it was.  With a
   medium mounted (robotfleet/pull/robot/media.py) the remote is fetched too,
   and the newer of the two verified releases taken.
3. Decide (robotfleet/pull/robot/decide.py): nothing new, wait for a wave or a
   maintenance window (meanwhile putting the release in place:
   robotfleet/pull/robot/prefetch.py), a halt, or apply.
4. To apply: download and verify the code archive and the wheels, unpack
   and check the tree, make the venv, all before any lock; then run the
   release's own converge (robotfleet/pull/robot/converge.py: the deploy under the
   roles' locks, in the release's code and venv) and read its outcome.
   Only an applied release is recorded, and becomes the code the agent
   runs from the next wake on.
5. The roles' status: from the converge run when there was one; else read
   again (a process: python, the roles, payloadctl, docker) only when a
   path the roles watch changed, the code the agent runs changed, or the
   heartbeat is due; else what the last read found.
6. Report (robotfleet/pull/robot/wake_report.py) to refs/reports/<robot>, when it
   says something new or its heartbeat is due; one line in the journal.
   While it holds a bundle's enrollment key, that key signs the robot's
   name and keys in the report (robotfleet/pull/protocol/enrollment.py).
   What it keeps between wakes: robotfleet/pull/robot/agent_state.py.
"""

from __future__ import annotations

import argparse
import datetime
import fcntl
import os
import secrets
import shutil
import time
from pathlib import Path

from robotfleet.pull.protocol import agent_files, platforms, reports, waves
from robotfleet.pull.protocol import record as records
from robotfleet.pull.protocol.path_signatures import watched
from robotfleet.pull.robot import agent_state, prepare, refusals, release_run, trust_state, verify, wake_report
from robotfleet.pull.robot import decide as deciding
from robotfleet.pull.robot.journal import Phases, cpu_seconds, journal_line
from robotfleet.pull.robot.transport import Remote, TransportError

# What ssh says when the git server knows none of the robot's keys: before
# `robotfleet pull-enroll` registered its own, for a robot that never read
# a release (one that did was enrolled: its key refused now is a failure).
ENROLLMENT_PENDING = "Permission denied (publickey"
# The agent's bytecode directory in its state directory, which earlier
# releases' units named (ROBOT_PULL_PYCACHE): unused now, and removed.
EARLIER_BYTECODE = "pycache"


def now() -> datetime.datetime:
    return datetime.datetime.now(datetime.timezone.utc).replace(microsecond=0)


class Outcome(Exception):
    """How this wake ends: the report's result and its one line."""

    def __init__(self, result: str, reason: str | None = None, refusal: str | None = None, wave: int | None = None):
        super().__init__(reason or result)
        self.result, self.reason, self.refusal, self.wave = result, reason, refusal, wave


class Wake:
    """One check of one robot (``config``: robotfleet/pull/protocol/agent_files.py)."""

    def __init__(self, config: agent_files.Config, clock=now):
        self.config = config
        self.state_dir = Path(config.state_dir)
        self.clock = clock
        self.remote = Remote(
            config.remote,
            self.state_dir / "releases",
            config.etc_dir,
            config.fetch_timeout,
            config.report_remote,
            config.report_shards,
            (config.keepalive_interval, config.keepalive_count_max),
        )
        self.state = agent_state.load_state(self.state_dir)
        self.record = None
        self.status: dict = {}
        self.status_time: str | None = None
        self.reference_time = clock()
        self.medium: Path | None = None  # a mounted release on media, this wake's source (robot/media.py)
        self.mounted: Path | None = None  # a medium mounted while the remote answered too: verify() chooses
        self.key_refused_by: str | None = None  # the remote that refused the robot's keys in this wake
        self.phases = Phases()

    # -- the steps ---------------------------------------------------------

    def check_disk(self) -> None:
        for path in (self.config.state_dir, self.config.docker_dir):
            if os.path.isdir(path):
                free = shutil.disk_usage(path).free // (1 << 20)
                if free < self.config.min_free_mb:
                    raise Outcome(
                        "failed",
                        f"only {free} MB free on {path}'s file system "
                        f"(pull_min_free_mb: {self.config.min_free_mb}); nothing was downloaded",
                    )

    def fetch(self) -> None:
        if self.config.media_dir:
            from robotfleet.pull.robot import media

            self.mounted = media.mounted(self.config.media_dir)
        try:
            self.remote.fetch_releases(self.config.branch)
        except TransportError as error:
            if self.mounted is not None:  # out of reach: the medium alone, verified by the same refresh
                self.medium, self.mounted = self.mounted, None
                return
            if not self.state.get("seen") and ENROLLMENT_PENDING in str(error):
                self.key_refused_by = self.remote.url
                raise Outcome(
                    "waiting",
                    f"waiting for enrollment: the fleet remote does not accept this robot's "
                    f"key yet (robotfleet pull-enroll registers it; {error})",
                ) from None
            raise Outcome("failed", f"fetch: {error}") from None

    def source(self) -> str:
        return str(self.medium or self.remote.repo)

    def verify(self):
        """The record, verified in full; the trust client (for downloads)."""
        if not (self.state_dir / "tuf" / "root.json").exists():
            root = Path(self.config.etc("root.json")).read_bytes()
            first = self.config.extra.get("trusted_time")
            verify.initialize(self.state_dir, root, records.parse_time(first, "trusted_time") if first else None)
        client = verify.Client(self.state_dir, self.source(), clock=self.clock)
        try:
            if self.mounted is None:
                self.record = client.refresh(applied=self.applied_version())
            else:  # the newer signed release of the two, a halt from either (robot/media.py)
                sources = [str(self.mounted), self.source()]
                client = verify.newest(self.state_dir, sources, self.applied_version(), self.clock)
                self.record, self.medium = client.record, self.mounted if client.source == sources[0] else None
        except refusals.Refused as refused:
            raise Outcome("refused", refused.line, refused.reason) from None
        self.reference_time = client.reference_time or self.clock()
        return client

    def applied_version(self) -> int:
        return int((self.state.get("applied") or {}).get("version") or 0)

    def decide(self) -> deciding.Decision:
        windows = [waves.parse_window(w) for w in self.config.windows]
        args = (
            self.record,
            self.config.robot,
            self.applied_version(),
            self.state.get("attempted"),
            self.reference_time,
            windows,
        )
        decision = deciding.decide(*args)
        if decision.earlier:
            try:
                found = self.remote.fetch_reports(list(decision.earlier))
            except TransportError as error:
                if self.medium is None:
                    raise Outcome("waiting", f"the earlier waves' reports: {error}", wave=decision.wave) from None
                found = {}  # out of reach from a medium: its wave's time alone decides
            failed = sum(
                reports.failed_for(report, self.record.version) for report in found.values() if "error" not in report
            )
            decision = deciding.decide(*args, failed=failed)
        return decision

    def apply(self, client, wave: int | None) -> Outcome:
        record, robot = self.record, self.config.robot
        platform = platforms.platform_key()
        wanted = [record.code, *record.wheels_for(platform)]
        try:
            with self.phases.timed("prepare"):
                files = client.download(wanted, self.state_dir / "targets")
                code = prepare.code_dir(self.state_dir, record, files[record.code])
                venv = (
                    prepare.venv_for(self.state_dir, {p: files[p] for p in record.wheels_for(platform)})
                    if record.wheels_for(platform)
                    else Path(os.path.realpath(self.state_dir / "venv"))
                )
                if self.medium is not None:  # its images too, checked (robot/media.py)
                    from robotfleet.pull.robot import media

                    media.load_images(client, record, self.config, platform.split("-", 1)[1], self.state_dir / "media")
        except refusals.Refused as refused:
            raise Outcome("refused", refused.line, refused.reason, wave) from None
        except prepare.Mismatch as error:
            raise Outcome("refused", f"release {record.version}: {error}", refusals.TAMPERED, wave) from None
        except (prepare.PrepareError, OSError) as error:
            return self.tried(Outcome("failed", f"release {record.version} could not be prepared: {error}", wave=wave))
        prepared = self.prepared()
        deployment = prepared["deployment"] if prepared else f"pull-{robot}-{record.version}-{secrets.token_hex(3)}"
        if prepared:
            ended = self.switched(prepared, wave)
            if ended is not None:
                return self.tried(ended)
        started = time.monotonic()  # the release's whole converge, also after its prepared switch
        said = release_run.converge(self.state_dir, record, robot, code, venv, "run", deployment)
        self.phases.add_run(time.monotonic() - started, said.get("took"))
        if said.get("row"):
            self.read_status(said, code)
        outcome = Outcome(*release_run.classify(said, record.version), wave=wave)
        if outcome.result == "applied":
            for link, target in ((self.state_dir / "code" / "current", code), (self.state_dir / "venv", venv)):
                previous = Path(os.path.realpath(link)) if link.exists() else None
                prepare.switch(link, target)
                prepare.prune(target.parent, {target, *([previous] if previous else [])})
            self.state["applied"] = {**reports.version_of(record), "time": record_time(self.clock())}
            self.state["fleet"] = record.fleet
            prepare.prune_targets(self.state_dir / "targets", set(files.values()))
        return self.tried(outcome)

    def prepared(self) -> dict | None:
        """This release's switch as its prefetch prepared it
        (robotfleet/pull/robot/window_switch.py), once: a second try is the whole converge's."""
        prefetched = self.state.get("prefetched") or {}
        found = prefetched.pop("switch", None) if prefetched.get("version") == self.record.version else None
        if isinstance(found, dict) and isinstance(found.get("switch"), list) and found.get("deployment"):
            return found
        return None

    def switched(self, prepared: dict, wave: int | None) -> Outcome | None:
        """The window's prepared switch: the outcome when it failed its gate
        (rolled back, or nothing to go back to); None when it applied, or
        gave way (its release gone: refused), for the whole converge."""
        with self.phases.timed("switch"):
            said = release_run.switch(prepared["switch"])
        if said.get("outcome") in ("rolled-back", "failed"):
            why = " ".join(str(said.get("message") or said["outcome"]).split())[:300]
            return Outcome(said["outcome"], f"release {self.record.version}: {why}", wave=wave)
        return None

    def tried(self, outcome: Outcome) -> Outcome:
        previous = self.state.get("attempted") or {}
        tries = previous.get("tries", 0) + 1 if previous.get("version") == self.record.version else 1
        self.state["attempted"] = {
            "version": self.record.version,
            "result": outcome.result,
            "tries": tries,
            "reason": outcome.reason,
        }
        return outcome

    # -- the wake ------------------------------------------------------------

    def run(self) -> tuple[dict, Outcome]:
        outcome = None
        try:
            self.check_disk()
            with self.phases.timed("fetch"):
                self.fetch()
            with self.phases.timed("verify"):
                client = self.verify()
            with self.phases.timed("decide"):
                decision = self.decide()
            if decision.result == deciding.APPLY:
                outcome = self.apply(client, decision.wave)
            elif decision.result == "waiting":  # time to put it in place: robotfleet/pull/robot/prefetch.py
                from robotfleet.pull.robot import prefetch

                with self.phases.timed("prefetch"):
                    outcome = Outcome(*prefetch.ahead(self, client, decision), wave=decision.wave)
            else:
                outcome = Outcome(decision.result, decision.reason, wave=decision.wave)
        except Outcome as ended:
            outcome = ended
        if self.status_time is None:
            with self.phases.timed("status"):
                self.roles_status()
        return wake_report.build(self, outcome), outcome

    # -- the roles' status ----------------------------------------------------

    def read_status(self, said: dict, code: Path) -> None:
        """Keep what a converge run (or status) just read, and what the
        roles' watched paths looked like before it read."""
        self.status, self.status_time = said.get("row") or {}, record_time(self.clock())
        self.state["status"] = {
            "row": self.status,
            "at": time.time(),
            "time": self.status_time,
            "watch": said.get("watch") or {},
            "code": os.path.realpath(code),
        }

    def roles_status(self) -> None:
        """The roles' status as the code the agent runs reads it: read again
        only when something it reads may have changed, or at the heartbeat."""
        code = self.state_dir / "code" / "current"
        last = self.state.get("status") or {}
        watch = last.get("watch") if isinstance(last.get("watch"), dict) else None
        age = time.time() - float(last.get("at") or 0)
        if (
            last.get("row") is not None
            and watch is not None
            and 0 <= age < self.config.heartbeat
            and last.get("code") == os.path.realpath(code)
            and watched(watch) == watch
        ):
            self.status, self.status_time = last["row"], last.get("time")
            return
        if not code.exists():
            self.status, self.status_time = {}, None
            return
        fleet = (self.state.get("fleet") or {}).get("path")
        self.read_status(release_run.status(self.state_dir, self.config.robot, fleet), code)


def record_time(moment: datetime.datetime) -> str:
    return moment.astimezone(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m robotfleet.pull.agent", description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", default=agent_files.CONFIG)
    args = parser.parse_args(argv)
    started = time.monotonic()
    try:
        text = Path(args.config).read_text()
        config = agent_files.named(agent_files.read_config(text, args.config))
    except (OSError, agent_files.ConfigError) as error:
        print(f"robot-pull: cannot start: {error}", flush=True)
        return 1
    state = Path(config.state_dir)
    state.mkdir(parents=True, exist_ok=True, mode=0o700)
    with open(state / "agent.lock", "a") as lock:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            print("robot-pull: another check is running; this one does nothing", flush=True)
            return 0
        for earlier in ("idle.json", *trust_state.EARLIER):  # what earlier releases' shortcuts kept: gone
            (state / earlier).unlink(missing_ok=True)
        if (state / EARLIER_BYTECODE).is_dir():
            shutil.rmtree(state / EARLIER_BYTECODE, ignore_errors=True)
        wake = Wake(config)
        report, outcome = wake.run()
        if wake.record is not None:
            wake.state["seen"] = reports.version_of(wake.record)
        with wake.phases.timed("report"):
            sent = wake_report.send(wake, report)
        agent_state.save_state(state, wake.state)
        report["check"]["cpu"] = cpu_seconds()
        report["check"].update(
            {
                "sent": wake.remote.cost.sent,
                "received": wake.remote.cost.received,
                "requests": wake.remote.cost.requests,
            }
        )
        # an up-to-date wake's line times no phases (as its earlier releases' idle check printed it)
        phases = wake.phases if outcome.result != "up-to-date" else None
        print(journal_line(report, sent, time.monotonic() - started, phases), flush=True)
    return 0
