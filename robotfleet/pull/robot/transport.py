"""The robot's side of the fleet remote: git over SSH (or HTTPS), bounded
in time, with the bytes each exchange moved.

- ``fetch_releases``: the releases branch at depth 1 into the agent's own
  repository, checked out (the TUF client reads that directory); protocol
  v2 asks the server for that one branch only; first one probe
  (robotfleet/pull/robot/probe.py; over SSH ``remote_git.ls_remote``): a
  branch still at the commit checked out is not fetched at all.
- ``fetch_reports``: the reports of named robots (the waves before this
  robot's), each asked for by its own prefix, read as the operator reads
  them (``report_store.read``: each robot's own row, never another's).
  With the reports sharded (``shards``, robotfleet/pull/protocol/report_shards.py),
  one fetch from the fleet remote: its own report refs (robots not moved to
  their shard yet) and the server's read copy of every shard
  (``report_store.read_copy``, kept as ``COPY``, so the next read fetches
  only what changed); a remote without that copy has each robot's own
  shard fetched, a few at once.
- ``push_report``: this robot's report as a one-file commit, force-pushed
  to ``refs/reports/<robot>`` (the only ref the server lets it write) of
  its shard; a push the shard refuses (the server's rules not rewritten for
  this shard count yet) goes to the fleet remote's, where it was before.

Over SSH, the robot's own key is offered first, then a first-boot bundle's
enrollment key if it still has one; once the server accepts the robot's own
key, the enrollment key is deleted (it was single-use).  The git server's
host keys are pinned (StrictHostKeyChecking, under one alias, so a new
address or port does not matter).  Bytes are ssh's own count of what went
over the connection ("Transferred: sent N, received M bytes"; its debug
level also names the key the server accepted); each ssh session is one
request (the counting: robotfleet/pull/robot/transport_cost.py).  git runs
through robotfleet/pull/robot/remote_git.py (bounded in time; over SSH, that
ssh and its log).

Over HTTPS (``https://host/path``: git's smart HTTP, or a static directory
served as a "dumb" remote, which cannot answer a shallow fetch, so the
branch is fetched whole there), the server's certificate is checked against
``remote-ca.pem`` in the agent's configuration directory when it is there
(a private CA the bundle or the role installed), else the system's CAs.
That is only the transport: the releases are trusted for their TUF
signatures.  Bytes and requests are git's own trace of its HTTP exchanges
(GIT_TRACE_CURL, read as it streams; credentials redacted).  Reports can be
pushed to another remote (``report_url``, e.g. SSH with the robot's key,
when the releases come from a static HTTPS mirror).
"""

from __future__ import annotations

import os
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from robotfleet.pull.protocol import agent_files, report_shards, report_store, reports
from robotfleet.pull.robot import probe, remote_git, ssh_options, transport_cost
from robotfleet.pull.robot.remote_git import git_error

HOST_KEY_ALIAS = agent_files.HOST_KEY_ALIAS
LOCAL_BRANCH = "refs/remotes/fleet/releases"
COPY = "refs/fleet-report-copy"  # the server's read copy of the shards' reports, as last fetched
_SHALLOW_REFUSED = "dumb http transport does not support shallow"
# What a server says of a repository or ref the robot may not write (gitolite, git's own).
_REFUSED = ("DENIED", "does not appear to be a git repository", "not found")
# A read of more robots than this asks for the repository's every report
# rather than each robot's by its prefix (then reads only the robots asked for).
PREFIXES_AT_MOST = 256


class TransportError(Exception):
    """The remote could not be reached or read (one line)."""


def is_https(url: str) -> bool:
    return url.startswith("https://")


class Remote:
    """The fleet remote as one robot reaches it."""

    def __init__(
        self,
        url: str,
        repo: str | Path,
        etc: str = agent_files.ETC,
        timeout: int = 300,
        report_url: str | None = None,
        shards: int = report_shards.SINGLE,
        keepalive: tuple[int, int] = ssh_options.KEEPALIVE,
    ):
        self.url = url
        self.report_url = report_url or url
        self.shards = report_shards.check_count(shards)
        self.repo = Path(repo)
        self.etc = etc
        self.timeout = timeout
        self.keepalive = keepalive  # a server silent that long is given up (ssh_options.silence)
        self.cost = transport_cost.Cost()
        self.accepted_key: str | None = None

    # -- git with bounds ---------------------------------------------------

    @property
    def silence(self) -> int:
        return ssh_options.silence(self.keepalive)

    def keys(self) -> list[str]:
        return remote_git.keys(self.etc)

    def _git(
        self,
        what: str,
        *args: str,
        network: bool = False,
        stdin: bytes | None = None,
        env: dict | None = None,
        url: str | None = None,
    ) -> bytes:
        """git with ``args`` in the agent's repository; ``network``: it
        talks to ``url`` (the fleet remote by default): bounded, and counted."""
        url = url or self.url
        if network and not is_https(url):  # over SSH (or a local path)
            ran = remote_git.over_ssh(self.repo, args, url, self.etc, self.timeout, stdin, env, self.keepalive)
            self.cost.add(what, ran.sent, ran.received, ran.seconds)
            self.accepted_key = ran.accepted or self.accepted_key
            if ran.error:
                raise TransportError(f"{what}: {ran.error}")
            return ran.out
        environment = remote_git.environment(env)
        trace = None
        options: list[str] = []
        if network:
            trace = transport_cost.CurlTrace()
            environment.update(GIT_TRACE_CURL="2", GIT_TRACE_REDACT="1")
            # curl gives up on a server that sent nothing for the keepalives' silence (under 1 byte a second)
            environment.update(GIT_HTTP_LOW_SPEED_LIMIT="1", GIT_HTTP_LOW_SPEED_TIME=str(self.silence))
            environment.pop("GIT_SSL_NO_VERIFY", None)
            options = ["-c", "http.sslVerify=true"]
            ca = f"{self.etc}/remote-ca.pem"
            if os.path.exists(ca):  # the environment's GIT_SSL_CAINFO would win over http.sslCAInfo
                environment["GIT_SSL_CAINFO"] = ca
        started = time.monotonic()
        argv = ["git", *options, "-C", str(self.repo), *args]
        try:
            code, out, err = remote_git.run(argv, environment, stdin, self.timeout, trace and trace.read)
        except remote_git.NoAnswer:
            raise TransportError(f"{what}: {remote_git.no_answer(url, self.timeout)}") from None
        except OSError as error:
            raise TransportError(f"{what}: cannot run git ({error})") from None
        finally:
            if trace is not None:
                self.cost.add(what, trace.sent, trace.received, time.monotonic() - started, trace.requests)
        if trace is not None:
            err = trace.stderr
        if code:
            raise TransportError(f"{what}: {git_error(err.decode(errors='replace'), code)}")
        return out

    def _init(self) -> None:
        if not (self.repo / ".git").is_dir():
            self.repo.mkdir(parents=True, exist_ok=True, mode=0o700)
            self._git("init", "init", "-q")
            # gc runs in this process (a oneshot unit would kill a detached
            # one), and what older fetches left goes at once.
            for key, value in (
                ("gc.autoDetach", "false"),
                ("gc.pruneExpire", "now"),
                ("core.logAllRefUpdates", "false"),
            ):
                self._git("init", "config", key, value)

    # -- the releases branch -----------------------------------------------

    def fetch_releases(self, branch: str = agent_files.BRANCH) -> str:
        """Fetch the releases branch and check it out; its commit id.  When
        the branch is still what the last completed fetch checked out, one
        probe says so and nothing is fetched (robotfleet/pull/robot/probe.py)."""
        self._init()
        memo = probe.read_memo(self.repo, self.url, branch)
        answer = self._probe(memo, branch) if memo else None
        if answer is not None and answer.commit == memo["commit"]:
            if answer.validators != memo.get("validators", {}):
                probe.write_memo(self.repo, self.url, branch, memo["commit"], memo["kind"], answer.validators)
            return memo["commit"]
        probe.forget(self.repo)  # from here until the checkout is complete, the work tree is no commit's
        spec = f"+refs/heads/{branch}:{LOCAL_BRANCH}"
        kind = "https" if is_https(self.url) else "git"
        try:
            self._git(
                "fetch",
                "-c",
                "protocol.version=2",
                "fetch",
                "--quiet",
                "--no-tags",
                "--depth=1",
                self.url,
                spec,
                network=True,
            )
        except TransportError as error:
            if _SHALLOW_REFUSED not in str(error):
                raise
            # A static ("dumb") HTTPS remote: the branch whole, then only what is new.
            self._git("fetch", "fetch", "--quiet", "--no-tags", self.url, spec, network=True)
            kind = "static"
        commit = self._git("fetch", "rev-parse", LOCAL_BRANCH).decode().strip()
        # Whatever is in the directory is made the commit's again (nothing
        # left over is read as part of the repository); a link the branch
        # holds is checked out as a file holding its target's name, never a link.
        self._git("checkout", "-c", "core.symlinks=false", "checkout", "-q", "--force", "--detach", commit)
        self._git("checkout", "clean", "-q", "-d", "-x", "--force")
        # a static copy's validators stand for this commit only if its info/refs named it
        validators = answer.validators if answer is not None and kind == "static" and answer.commit == commit else {}
        probe.write_memo(self.repo, self.url, branch, commit, kind, validators)
        return commit

    def _probe(self, memo: dict, branch: str) -> probe.Answer | None:
        """What the remote says the branch is now, in one exchange (None: it
        could not say; the fetch then asks)."""
        started = time.monotonic()
        if is_https(self.url):
            ca = f"{self.etc}/remote-ca.pem"
            answer = probe.https(self.url, branch, memo, ca if os.path.exists(ca) else None, self.timeout, self.silence)
        else:
            answer = remote_git.ls_remote(self.repo, self.url, branch, self.etc, self.timeout, self.keepalive)
        seconds = time.monotonic() - started
        if answer is not None:
            self.cost.add("probe", answer.sent, answer.received, seconds)
            self.accepted_key = answer.accepted or self.accepted_key
            if answer.error:  # over SSH: as any exchange's failure
                raise TransportError(f"probe: {answer.error}")
        return answer

    # -- reports -----------------------------------------------------------

    def fetch_reports(self, robots: list[str]) -> dict[str, dict]:
        """robot -> its report as the remote has it now, parsed, or {"robot",
        "error"} when it cannot be read (robots without a report ref left out)."""
        if not robots:
            return {}
        self._init()
        # the fleet remote: where robots not moved to their shard report, and the server's read copy of the shards
        fleet = self._reports_of(None, robots)
        if not self.shards:
            return fleet
        if report_store.has(self.repo, COPY):
            try:
                return report_store.merged([fleet, report_store.read_copy(self.repo, COPY, self.shards, set(robots))])
            except reports.ReportError as error:
                raise TransportError(f"reports: {error}") from None
        by_shard = report_shards.spread(robots, self.shards)
        with ThreadPoolExecutor(max_workers=min(report_store.FETCHERS, len(by_shard))) as pool:
            return report_store.merged([fleet, *pool.map(lambda item: self._reports_of(*item), by_shard.items())])

    def _reports_of(self, shard: int | None, robots: list[str]) -> dict[str, dict]:
        """The reports of ``robots`` (all of shard ``shard``) from that shard
        (None: the fleet remote), each read only under its own name."""
        local = "refs/fleet-reports/" if shard is None else f"refs/fleet-shards/{shard}/"
        specs = [f"+refs/reports/{robot}*:{local}{robot}*" for robot in robots]
        if len(specs) > PREFIXES_AT_MOST:  # git matches each refspec against each ref: 7,500 of them took 31 s of CPU
            specs = [f"+refs/reports/*:{local}*"]  # every report of the repository, the wanted ones read
        if shard is None and self.shards:  # the read copy, kept: the next read fetches only what changed
            specs.append(f"+{report_store.COPY}*:{COPY}*")

        try:
            # Shards are fetched at once into this repository: no FETCH_HEAD, no gc between them.
            self._git(
                "reports",
                "-c",
                "protocol.version=2",
                "-c",
                "gc.auto=0",
                "fetch",
                "--quiet",
                "--no-tags",
                "--no-write-fetch-head",
                *(["--prune"] if shard is None and self.shards else []),  # a copy the server no longer keeps
                report_shards.shard_url(self.url, shard),
                *specs,
                network=True,
            )
            return report_store.read(self.repo, local, set(robots), self.timeout)
        except reports.ReportError as error:
            raise TransportError(f"reports: {error}") from None
        finally:
            if shard is not None:
                self._forget(local)

    def _forget(self, prefix: str) -> None:
        """Delete the refs a shard's read fetched under ``prefix`` (their
        objects stay until gc, so the next read downloads nothing): git checks
        every fetch against every local ref (``rev-list --not --all``), and at
        10,000 robots the 7,500 refs a last wave's read kept made each of its
        256 shard fetches walk all of them (0.7 s of CPU each, not 0.16).  The
        fleet remote's are kept: one fetch, and rewriting 10,000 refs on each
        read cost more than the walk."""
        listed = self._git("reports", "for-each-ref", "--format=delete %(refname)", prefix)
        if listed.strip():
            self._git("reports", "update-ref", "--stdin", stdin=listed)

    def push_report(self, robot: str, report: bytes) -> str:
        """Force-push ``report`` as refs/reports/<robot> of the robot's shard; the commit id."""
        self._init()
        blob = self._git("report", "hash-object", "-w", "--stdin", stdin=report).decode().strip()
        tree = self._git("report", "mktree", stdin=f"100644 blob {blob}\treport.json\n".encode()).decode().strip()
        commit = self._git("report", "commit-tree", tree, "-m", f"report of {robot}").decode().strip()
        url = report_shards.report_url(self.report_url, robot, self.shards)
        try:
            self._push(url, commit, robot)
        except TransportError as error:
            if url == self.report_url or not any(word in str(error) for word in _REFUSED):
                raise
            try:
                self._push(self.report_url, commit, robot)
            except TransportError as again:
                raise TransportError(f"{error}; and to {self.report_url}: {again}") from None
        return commit

    def _push(self, url: str, commit: str, robot: str) -> None:
        self._git("report", "push", "--quiet", "--force", url, f"{commit}:refs/reports/{robot}", network=True, url=url)

    def retire_enrollment_key(self) -> bool:
        """Delete the enrollment key once the server took the robot's own key."""
        enroll = f"{self.etc}/enroll_ed25519"
        if self.accepted_key != f"{self.etc}/id_ed25519" or not os.path.exists(enroll):
            return False
        for path in (enroll, f"{enroll}.pub"):
            if os.path.exists(path):
                os.unlink(path)
        return True
