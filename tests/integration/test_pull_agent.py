"""The pull agent's wake (robotfleet/pull/robot/agent.py) against a real TUF
repository and a real git remote (file://), with a release whose code is a
small tree: its robotfleet.commands.converge answers as the contract says
(one JSON line), the way a release's own code does, without provisioning
this machine.  What a converge run does on a robot is the end-to-end test's."""

from __future__ import annotations

import datetime
import gzip
import hashlib
import json
import os
import subprocess
import sys
import tarfile
from pathlib import Path

import pytest

from robotfleet.pull.protocol import agent_files, path_signatures, reports, tree
from robotfleet.pull.robot import agent, agent_state, journal, transport, wake_report
from tests.integration import craftedgit
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
        self.config = agent_files.Config(
            robot="robot1",
            remote=f"file://{self.bare}",
            interval=60,
            jitter=5,
            state_dir=str(self.state),
            etc_dir=str(self.etc),
            docker_dir=str(base / "none"),
            min_free_mb=0,
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


@pytest.fixture
def world(tmp_path):
    return World(tmp_path)


def test_a_new_release_is_verified_applied_recorded_and_reported(world):
    record = world.release(1)
    report, outcome, sent = world.wake()
    assert (outcome.result, outcome.reason) == ("applied", "release 1 applied")
    assert sent == "report sent"
    state = agent_state.load_state(world.state)
    assert state["applied"]["version"] == 1 and state["fleet"]["path"] == "inventories/robots.yaml"
    assert os.path.realpath(world.state / "code" / "current") == str(world.state / "code" / record.tree_sha256)
    assert (world.state / "last-run.log").read_text().startswith("ran pull-robot1-1-")
    pushed = world.pushed_report()
    assert pushed["result"] == "applied" and pushed["applied"]["version"] == 1 and pushed["key"]
    assert pushed["status"]["release"] == "r-applied"
    # the next wakes find nothing new and read the status with the applied code; the second says nothing new
    report, outcome, sent = world.wake()
    assert outcome.result == "up-to-date" and sent == "report sent"
    assert world.pushed_report()["status"]["release"] == "r-applied"
    report, outcome, sent = world.wake()
    assert outcome.result == "up-to-date" and sent == "report unchanged"


def test_a_rolled_back_release_is_reported_not_recorded_and_not_tried_again(world):
    world.release(1)
    world.wake()
    world.release(2)
    report, outcome, _ = world.wake("rolled-back")
    assert outcome.result == "rolled-back" and "rolled back to y" in outcome.reason
    state = agent_state.load_state(world.state)
    assert state["applied"]["version"] == 1 and state["attempted"]["result"] == "rolled-back"
    assert world.pushed_report()["attempted"] == {"version": 2, "result": "rolled-back", "tries": 1}
    _, again, _ = world.wake("applied")  # not tried a second time
    assert again.result == "rolled-back" and "waiting for a newer release" in again.reason


@pytest.mark.parametrize("crafted", ["a tree forging robot3's report", "JSON nested 200,000 deep"])
def test_a_robot_s_crafted_report_neither_forges_another_s_nor_stops_a_later_wave(world, crafted):
    """Release 3's canaries are robot3 and robot2, robot1 comes after them:
    robot3 rolled it back, so robot1 halts (no failure allowed), whatever
    robot2 pushed as its report."""
    world.release(3, robots=("robot1", "robot2", "robot3"), canary="2")
    rolled_back = reports.build(
        "robot3", NOW, "rolled-back", attempted={"version": 3, "result": "rolled-back", "tries": 1}
    )
    transport.Remote(f"file://{world.bare}", world.base / "robot3", str(world.base / "etc3"), timeout=30).push_report(
        "robot3", reports.to_bytes(rolled_back)
    )
    work = craftedgit.workspace(world.base / "hostile")
    if crafted.startswith("a tree"):
        applied = reports.build("robot3", NOW, "applied", attempted={"version": 3, "result": "applied", "tries": 1})
        entry = f"040000 tree {craftedgit.forging_tree(work, reports.to_bytes(applied))}\treport.json"
    else:
        entry = f"100644 blob {craftedgit.blob(work, b'[' * 200000)}\treport.json"
    craftedgit.push_report_entry(world.bare, work, "robot2", entry)
    _, outcome, sent = world.wake()
    assert (outcome.result, outcome.wave) == ("stopped", 1)
    assert outcome.reason == "wave 1 stopped by the failure budget: 1 robot(s) of the earlier waves failed (budget 0)"
    assert sent == "report sent" and not (world.state / "last-run.log").exists()


def test_a_tampered_code_archive_is_refused_before_anything_runs(world, tmp_path):
    world.release(1)
    world.wake()
    other, _, _ = code_archive(tmp_path / "other", 9) if (tmp_path / "other").mkdir() is None else (None, None, None)
    world.release(2, archive=other)  # signed, but not the tree the record binds
    report, outcome, _ = world.wake()
    assert (outcome.result, outcome.refusal) == ("refused", "tampered")
    assert "the code archive's tree hashes to" in outcome.reason
    assert agent_state.load_state(world.state)["applied"]["version"] == 1


def test_a_refused_repository_changes_nothing_and_says_why(world):
    world.release(1)
    world.wake()
    before = sorted(p.name for p in world.state.iterdir())
    pullkit.edit_json(
        world.fleet.repository.metadata / "timestamp.json",
        lambda d: d["signed"].update(version=d["signed"]["version"] + 1),
    )
    world.push()
    report, outcome, sent = world.wake()
    assert (outcome.result, outcome.refusal) == ("refused", "tampered") and sent == "report sent"
    assert world.pushed_report()["refusal"] == "tampered"
    assert agent_state.load_state(world.state)["applied"]["version"] == 1
    assert sorted(p.name for p in world.state.iterdir()) == before


def test_a_release_not_for_this_robot_and_a_full_disk(world):
    world.release(1, robots=("robot2",))
    _, outcome, _ = world.wake()
    assert (outcome.result, outcome.reason) == ("up-to-date", "release 1 is not for robot1")
    world.config = agent_files.Config(**{**world.config.__dict__, "min_free_mb": 1 << 20})
    _, outcome, _ = world.wake()
    assert outcome.result == "failed" and "MB free on" in outcome.reason and "pull_min_free_mb" in outcome.reason


def test_an_unreachable_remote_is_a_failed_check_not_a_crash(world):
    world.config = agent_files.Config(**{**world.config.__dict__, "remote": f"file://{world.base}/nowhere.git"})
    report, outcome, sent = world.wake()
    assert outcome.result == "failed" and outcome.reason.startswith("fetch: ")
    assert sent.startswith("report not sent")
    # when it does reach the operator (another report remote, a later push), status counts the robot out of
    # reach in its own words, not as a failed release (issue 54, item 9)
    from robotfleet.commands import pullstatus, status

    data = {"pull_interval": 60, "pull_jitter": 5, "pull_stale_after": 3, "pull_heartbeat": 600}
    row = pullstatus.row("robot1", reports.parse(reports.to_bytes(report), "robot1"), data, NOW, "url")
    assert row["error"] == f"out of reach of its releases remote: {outcome.reason}"
    assert (status.state_of(row), status.exit_code([row]), status.reachable(row)) == (
        "unreachable",
        3,
        "pull: remote out of reach",
    )


def test_a_robot_whose_key_the_remote_does_not_know_yet_waits_for_enrollment(world):
    """Between the push deploy that installs the agent and robotfleet
    pull-enroll, the git server refuses the robot's key (a real SSH server
    here that knows none): the check says it waits for enrollment, not that
    it failed.  A robot that has read releases before was enrolled: its key
    refused then is a failure."""
    from robotfleet.pull.robot import transport
    from tests.integration import sshserver

    (world.etc / "id_ed25519.pub").unlink()
    subprocess.run(["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-f", str(world.etc / "id_ed25519")], check=True)
    server = sshserver.ssh_server()  # accepts no key: gitolite before pull-enroll
    try:
        key = server.host_key
        (world.etc / "known_hosts").write_text(f"{transport.HOST_KEY_ALIAS} {key.get_name()} {key.get_base64()}\n")
        world.config = agent_files.Config(
            **{**world.config.__dict__, "remote": f"ssh://git@127.0.0.1:{server.port}/fleet"}
        )
        report, outcome, sent = world.wake()
        assert outcome.result == "waiting", outcome.reason
        assert outcome.reason.startswith(
            "waiting for enrollment: the fleet remote does not accept this robot's key "
            "yet (robotfleet pull-enroll registers it; fetch: "
        )
        assert "Permission denied (publickey" in outcome.reason
        assert sent == "report not sent (the fleet remote refused this robot's key in this check)"
        assert server.connections == 1  # the report was not tried on the server that had just refused the key
        agent_state.save_state(world.state, {**agent_state.load_state(world.state), "seen": {"version": 1}})
        _, outcome, _ = world.wake()
        assert outcome.result == "failed" and outcome.reason.startswith("fetch: ")
    finally:
        server.close()


def test_a_release_fetched_over_https_is_verified_applied_and_reported_elsewhere(world, tmp_path):
    """The releases from a static HTTPS mirror (its CA in remote-ca.pem),
    the report pushed to the report remote: the same wake."""
    from tests.integration import httpsgit

    ca, cert, key = httpsgit.make_ca(tmp_path / "tls")
    world.release(1)
    subprocess.run(["git", "-C", str(world.bare), "update-server-info"], check=True)
    server = httpsgit.Server(world.base, cert, key, smart=False)
    try:
        (world.etc / "remote-ca.pem").write_bytes(ca.read_bytes())
        world.config = agent_files.Config(
            **{**world.config.__dict__, "remote": server.url("fleet.git"), "report_remote": f"file://{world.bare}"}
        )
        _, outcome, sent = world.wake()
        assert (outcome.result, sent) == ("applied", "report sent") and server.requests > 0
        assert world.pushed_report()["applied"]["version"] == 1
    finally:
        server.close()


def test_the_journal_line_says_the_outcome_and_its_cost():
    report = {
        "result": "refused",
        "seen": {"version": 3},
        "reason": "timestamp.json: expired",
        "check": {"cpu": 0.42, "sent": 1200, "received": 3400, "requests": 2},
    }
    assert journal.journal_line(report, "report sent", 1.25) == (
        "robot-pull: refused (release 3): timestamp.json: expired; 1.2 s, 0.42 s CPU, sent 1200 B, "
        "received 3400 B in 2 requests; report sent"
    )
    phases = journal.Phases()
    phases.add("fetch", 0.2)
    phases.add("verify", 0.5)
    phases.add("fetch", 0.1)
    phases.add("ignored", -1)
    assert journal.journal_line(report, "report sent", 1.25, phases).endswith(
        "in 2 requests; report sent [fetch 0.30 s, verify 0.50 s]"
    )


def test_an_applying_wake_s_journal_line_says_where_its_seconds_went(world):
    world.release(1)
    awake = agent.Wake(world.config, clock=lambda: NOW)
    os.environ["STUB"] = "applied"
    try:
        report, outcome = awake.run()
    finally:
        del os.environ["STUB"]
    took = awake.phases.seconds
    assert outcome.result == "applied"
    assert list(took) == ["fetch", "verify", "decide", "prepare", "load", "deploy", "status"]
    # the converge's own figures as it timed them; the rest of its process's time is the release's loading
    assert (took["deploy"], took["status"]) == (0.02, 0.01) and took["load"] >= 0
    line = journal.journal_line(report, "report sent", 2.0, awake.phases)
    assert line.endswith("; report sent [" + ", ".join(f"{k} {v:.2f} s" for k, v in took.items()) + "]")


def test_a_converge_that_times_nothing_leaves_its_whole_time_as_load():
    phases = journal.Phases()
    phases.add_run(1.5, None)
    phases.add_run(1.0, ["not", "a", "dict"])
    # what the converge cannot have spent, and what is not a figure, is not taken from it
    phases.add_run(1.0, {"deploy": 2.0, "status": "x", "other": 0.5})
    phases.add_run(2.0, {"deploy": 1.5, "status": True})
    assert phases.seconds == {"load": 4.0, "deploy": 1.5}


def test_the_agent_configuration_is_checked_field_by_field(tmp_path):
    good = agent_files.Config(robot="robot1", remote="ssh://g@h/fleet").to_json()
    assert agent_files.read_config(good).robot == "robot1"
    for change, line in (
        (lambda d: d.pop("robot"), "robot: required"),
        (lambda d: d.update(interval=0), "interval"),
        (lambda d: d.update(extra_field=1), "unknown field 'extra_field'"),
        (lambda d: d.update(state_dir="var/lib"), "state_dir: expected an absolute path"),
        (lambda d: d.update(robot="a b"), "is not a robot name"),
    ):
        data = json.loads(good)
        change(data)
        with pytest.raises(agent_files.ConfigError, match=line):
            agent_files.read_config(json.dumps(data))
    config = tmp_path / "agent.json"
    config.write_text("{")
    assert agent.main(["--config", str(config)]) == 1


def test_the_enrollment_key_goes_once_the_remote_took_the_robot_s_own_key_even_with_nothing_to_report(world):
    world.release(1)
    world.wake()
    world.wake()
    (world.etc / "enroll_ed25519").write_text("k")
    awake = agent.Wake(world.config, clock=lambda: NOW)
    report, _ = awake.run()
    awake.state = agent_state.load_state(world.state)
    awake.remote.accepted_key = str(world.etc / "id_ed25519")  # what ssh's log said (file:// has no ssh)
    said = wake_report.send(awake, report)
    assert said.startswith("report unchanged; the enrollment key is retired")
    assert not (world.etc / "enroll_ed25519").exists()


def test_a_robot_holding_its_bundle_s_enrollment_key_proves_its_report_and_keeps_the_proof_once_it_is_retired(world):
    from robotfleet.pull.operator import enrollments
    from robotfleet.pull.protocol import enrollment

    key = world.etc / "enroll_ed25519"
    subprocess.run(["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-f", str(key)], check=True)
    kept = {"robot1": {"enroll_key_sha256": enrollment.key_sha256((world.etc / "enroll_ed25519.pub").read_text())}}
    world.release(1)
    world.wake()
    first = world.pushed_report()
    assert first["enrollment"]["key"] == " ".join((world.etc / "enroll_ed25519.pub").read_text().split()[:2])
    assert enrollments.verify(first, kept, "enrollments.json") == "robot"  # as robotfleet pull-enroll checks it
    for path in (key, world.etc / "enroll_ed25519.pub"):  # retired, as the agent does once its own key is taken
        path.unlink()
    assert world.wake()[0]["enrollment"] == first["enrollment"]  # the same names and keys: the same proof
    (world.etc / "id_ed25519.pub").write_text(pullkit_key().replace("AAAAIGbig", "AAAAIGbiX"))  # another own key
    assert world.wake()[2] == "report sent"
    assert world.pushed_report()["enrollment"] is None  # nothing left to sign it with
