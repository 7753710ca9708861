"""A robot's pull agent against a fleet remote on this machine (a bare git
repository, file://): a signed release repository (tests/unit/pullkit.py),
release records and code archives whose converge is a stub (STUB: it says
applied, failed or prepared as $STUB asks), and the agent's own wake,
report and state; https_world serves the same remote over HTTPS.  The
integration tests of the agent drive it."""

from __future__ import annotations

import datetime
import gzip
import hashlib
import os
import subprocess
import sys
import tarfile
import time
from pathlib import Path

from robotfleet.pull.protocol import agent_files, path_signatures, reports, tree
from robotfleet.pull.robot import agent, agent_state, wake_report
from roles.payload import installed_files
from tests.integration import httpsgit
from tests.unit import pullkit
from tests.unit.pullkit import NOW

STUB = """import json, os, sys
from robotfleet.pull.protocol.path_signatures import watched
args = sys.argv[1:]
if os.environ.get("STUB_LOG"):
    with open(os.environ["STUB_LOG"], "a") as runs:
        runs.write(args[0] + "\\n")
watch = watched(filter(None, [os.environ.get("STUB_WATCH")]))
row = {"host": "robot1", "reachable": True, "release": "r-" + os.environ.get("STUB", "applied"),
       "health": os.environ.get("STUB_HEALTH", "healthy")}
if args[0] == "status":
    print(json.dumps({"row": row, "missing": [], "watch": watch}))
    raise SystemExit(0)
deployment = args[args.index("--deployment") + 1]
with open(os.path.join(args[args.index("--work") + 1], "pyinfra.log"), "w") as log:
    log.write("ran " + deployment)
if args[0] == "prepare":  # STUB_PREPARE: why the window would run the whole converge, else prepared
    why = os.environ.get("STUB_PREPARE")
    switch = [sys.executable, "-c", "import json, os; o = os.environ.get('STUB_SWITCH', 'applied'); "
              "print(json.dumps({'ok': o == 'applied', 'outcome': o, 'message': 'payload: release r-prepared ' + o}))"]
    if os.environ.get("STUB_LOG"):
        switch[-1] += "; open(os.environ['STUB_LOG'], 'a').write('switch' + chr(10))"
    prepared = {"role": "payload", "target": "r-prepared", "switch": switch, "deployment": deployment}
    print(json.dumps({"prepared": None if why else prepared,
                      "why": why or "payload: release r-prepared is prepared", "took": {"plan": 0.01}}))
    raise SystemExit(0)
mode = os.environ.get("STUB", "applied")
if mode == "applied":
    print(json.dumps({"exit": 0, "row": row, "results": [{"role": "payload", "ok": True, "why": "healthy",
                      "outcome": "applied"}], "missing": [], "errors": [], "watch": watch,
                      "took": {"deploy": 0.02, "status": 0.01}}))
else:
    print(json.dumps({"exit": 1, "row": row, "results": [{"role": "payload", "ok": False,
                      "why": "release x failed (unhealthy); rolled back to y", "outcome": mode}],
                      "missing": [], "errors": ["[@local] Error"]}))
"""


def code_archive(base: Path, version: int) -> tuple[Path, str, str]:
    """A release's code: (archive, tree hash, fleet file hash)."""
    files = {
        "robotfleet/__init__.py": "",
        "robotfleet/commands/__init__.py": "",
        "robotfleet/commands/converge.py": STUB,
        "robotfleet/pull/__init__.py": "",
        "robotfleet/pull/protocol/agent_files.py": Path(agent_files.__file__).read_text(),
        "robotfleet/pull/protocol/path_signatures.py": Path(path_signatures.__file__).read_text(),
        "inventories/robots.yaml": f"# release {version}\n",
    }
    root = base / f"tree-{version}"
    for name, text in files.items():
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_text(text)
    archive = base / f"code-{version}.tar.gz"
    with gzip.open(archive, "wb") as raw, tarfile.open(fileobj=raw, mode="w") as tar:
        for name in sorted(files):
            tar.add(root / name, arcname=name)
    fleet_sha = hashlib.sha256(files["inventories/robots.yaml"].encode()).hexdigest()
    return archive, tree.tree_sha256(tree.entries_of_directory(root)), fleet_sha


class World:
    def __init__(self, base: Path):
        self.base = base
        self.fleet = pullkit.Fleet(base)
        self.bare = base / "fleet.git"
        subprocess.run(["git", "init", "-q", "--bare", str(self.bare)], check=True)
        self.etc, self.state = base / "etc", base / "state"
        self.etc.mkdir()
        (self.etc / "root.json").write_bytes((self.fleet.repository.metadata / "root.json").read_bytes())
        (self.etc / "id_ed25519.pub").write_text(pullkit_key())
        venv = self.state / "venvs" / "stub" / "bin"
        venv.mkdir(parents=True)
        os.symlink(sys.executable, venv / "python")
        os.symlink("venvs/stub", self.state / "venv")
        helper = base / "payloadctl"  # the payload's image helper, as roles/payload installs it
        helper.write_bytes(installed_files.helper_bytes())
        self.config = agent_files.Config(
            robot="robot1",
            remote=f"file://{self.bare}",
            interval=60,
            jitter=5,
            state_dir=str(self.state),
            etc_dir=str(self.etc),
            docker_dir=str(base / "none"),
            min_free_mb=0,
            extra={"image_helper": [sys.executable, str(helper)]},
        )

    def record(self, version: int, robots, canary="1", images=None, wheels=None, pause=0):
        """Release ``version``'s record (code archive made in base) and its archive: (record, archive)."""
        record, waves = pullkit.module("protocol.record"), pullkit.module("protocol.waves")
        built_archive, tree_sha, fleet_sha = code_archive(self.base, version)
        built = record.build(
            version,
            NOW,
            NOW + datetime.timedelta(days=30),
            hashlib.sha1(bytes([version])).hexdigest(),
            tree_sha,
            "inventories/robots.yaml",
            fleet_sha,
            list(robots),
            images or {},
            wheels or {},
            waves.parse_plan({"canary": canary, "waves": ["100%"], "pause": pause, "max_failed": "0"}),
        )
        return built, built_archive

    def release(self, version: int, robots=("robot1", "robot2"), archive=None, canary="1"):
        built, built_archive = self.record(version, robots, canary)
        self.fleet.repository.publish(
            built, {built.code: archive or built_archive}, self.fleet.keys.signer("online"), self.fleet.expiry, NOW
        )
        self.push()
        return built

    def push(self):
        repo = self.fleet.repository.path
        if not (repo / ".git").exists():
            subprocess.run(["git", "-C", str(repo), "init", "-q"], check=True)
        env = dict(
            os.environ,
            GIT_AUTHOR_NAME="op",
            GIT_AUTHOR_EMAIL="op@x",
            GIT_COMMITTER_NAME="op",
            GIT_COMMITTER_EMAIL="op@x",
        )
        for args in (
            ["add", "-A", "metadata", "targets"],
            ["commit", "-q", "--allow-empty", "-m", "publish"],
            ["push", "-q", "--force", str(self.bare), "HEAD:refs/heads/robotfleet/releases"],
        ):
            subprocess.run(["git", "-C", str(repo), *args], check=True, env=env, capture_output=True)

    def wake(self, stub="applied", monkeypatch=None):
        os.environ["STUB"] = stub
        try:
            awake = agent.Wake(self.config, clock=lambda: NOW)
            report, outcome = awake.run()
            sent = wake_report.send(awake, report)
            agent_state.save_state(self.state, awake.state)
        finally:
            del os.environ["STUB"]
        return report, outcome, sent

    def pushed_report(self) -> dict:
        data = subprocess.run(
            ["git", "-C", str(self.bare), "show", "refs/reports/robot1:report.json"], check=True, capture_output=True
        ).stdout
        return reports.parse(data, "robot1")


def pullkit_key() -> str:
    return "ssh-ed25519 AAAAC3NzaC1lZDI1NTE5AAAAIGbigA6mqsYKDD3V4SGhrWodxIaju5HYfXtBYAQEvqW0 robot-pull@robot1\n"


def serve_static(world):
    """The published branch as a static copy's files, last written over a minute ago."""
    subprocess.run(["git", "-C", str(world.bare), "update-server-info"], check=True)
    past = time.time() - 120
    os.utime(world.bare / "info" / "refs", (past, past))


def https_world(tmp_path, tls, smart: bool) -> World:
    """A World whose fleet remote is served over HTTPS (``tls``: httpsgit.make_ca's
    CA, certificate and key): git's smart HTTP, or a static copy; reports still go to file://."""
    world = World(tmp_path)
    ca, cert, key = tls
    world.release(1)
    serve_static(world)
    world.server = httpsgit.Server(world.base, cert, key, smart=smart)
    (world.etc / "remote-ca.pem").write_bytes(ca.read_bytes())
    world.config = agent_files.Config(
        **{**world.config.__dict__, "remote": world.server.url("fleet.git"), "report_remote": f"file://{world.bare}"}
    )
    return world
