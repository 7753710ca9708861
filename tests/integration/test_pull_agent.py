"""The pull agent's wake (robotfleet/pull/robot/agent.py) against a real TUF
repository and a real git remote (file://), with a release whose code is a
small tree: its robotfleet.commands.converge answers as the contract says
(one JSON line), the way a release's own code does, without provisioning
this machine.  What a converge run does on a robot is the end-to-end test's."""

from __future__ import annotations

import json
import os
import subprocess

import pytest

from robotfleet import status_parts
from robotfleet.pull.protocol import agent_files, reports
from robotfleet.pull.robot import agent, agent_state, journal, transport, wake_report
from tests.integration import craftedgit
from tests.integration.pullworld import World, code_archive, pullkit_key
from tests.unit import pullkit
from tests.unit.pullkit import NOW


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
    from robotfleet.commands import status
    from robotfleet.commands.pull import status as pullstatus

    data = {"pull_interval": 60, "pull_jitter": 5, "pull_stale_after": 3, "pull_heartbeat": 600}
    row = pullstatus.row("robot1", reports.parse(reports.to_bytes(report), "robot1"), data, NOW, "url")
    assert row["error"] == f"out of reach of its releases remote: {outcome.reason}"
    assert (status_parts.state_of(row), status.exit_code([row]), status.reachable(row)) == (
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
