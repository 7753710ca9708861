"""An idle check on the wire (robotfleet/pull/robot/probe.py): when the
releases branch is still what the last fetch checked out, one exchange says
so and nothing is fetched: over HTTPS one request from the agent itself (a
static copy: a conditional GET answered 304; git's smart HTTP: one ls-refs),
over SSH one session asking ls-refs only.  Against real servers on
127.0.0.1: git's own http-backend and a static copy behind TLS
(tests/integration/httpsgit.py), git's upload-pack behind an SSH server
(tests/integration/gitssh.py); the agent's wake is test_pull_agent.py's."""

from __future__ import annotations

import datetime
import os
import time

import pytest

from robotfleet.pull.protocol import agent_files
from robotfleet.pull.robot import agent, agent_state, probe, transport
from tests.integration import gitssh, httpsgit
from tests.integration.pullworld import World, https_world, serve_static
from tests.unit.pullkit import NOW


@pytest.fixture(scope="module")
def tls(tmp_path_factory):
    return httpsgit.make_ca(tmp_path_factory.mktemp("tls"))


@pytest.fixture(params=["static", "smart"])
def over_https(request, tmp_path, tls):
    world = https_world(tmp_path, tls, request.param == "smart")
    yield world
    world.server.close()


def idle(world):
    """An idle check: its outcome, what it cost, and the server's requests."""
    before = world.server.requests
    awake = agent.Wake(world.config, clock=lambda: NOW)
    report, outcome = awake.run()
    agent_state.save_state(world.state, awake.state)
    return outcome, awake.remote.cost, world.server.requests - before


def test_an_idle_check_over_https_is_one_request_of_at_most_2_kb(over_https):
    world = over_https
    assert world.wake()[1].result == "applied"
    world.wake()  # a static copy's first probe learns its validators
    outcome, cost, requests = idle(world)
    assert outcome.result == "up-to-date"
    assert requests == 1 and cost.requests == 1 and [e["what"] for e in cost.exchanges] == ["probe"]
    # Python's TLS server sends two session tickets after the handshake (509
    # bytes here; OpenSSL servers' default too) that a new process per check
    # cannot use; smart HTTP's answer carries its no-cache headers.
    assert 0 < cost.sent + cost.received <= (2560 if world.server.smart else 2048), cost.as_dict()


def test_a_new_release_is_seen_at_the_next_check_after_idle_ones(over_https):
    world = over_https
    world.wake()
    idle(world)
    world.release(2)
    serve_static(world)
    os.utime(world.bare / "info" / "refs", (time.time() - 90, time.time() - 90))  # later than the last one's
    report, outcome, _ = world.wake()
    assert outcome.result == "applied" and report["applied"]["version"] == 2


def test_a_halt_after_idle_checks_is_seen_at_the_next_check(over_https):
    from robotfleet.pull.operator import publishing

    world = over_https
    world.wake()
    idle(world)
    publishing.halt(world.fleet.repository, world.fleet.keys, "canary crash-loops", world.fleet.expiry, NOW)
    world.push()
    serve_static(world)
    os.utime(world.bare / "info" / "refs", (time.time() - 90, time.time() - 90))
    _, outcome, _ = world.wake()
    assert outcome.result == "halted", outcome.reason


def test_a_static_copy_written_within_the_minute_is_not_trusted_to_answer_304(tmp_path, tls):
    """A Last-Modified within a minute of the answer's Date may name two
    versions of info/refs written in the same second: not kept as a validator."""
    world = https_world(tmp_path, tls, smart=False)
    try:
        os.utime(world.bare / "info" / "refs")  # written now
        world.wake()
        world.wake()
        memo = probe.read_memo(world.state / "releases", world.config.remote, world.config.branch)
        assert memo["kind"] == "static" and "last_modified" not in memo["validators"]
        outcome, cost, requests = idle(world)  # a full GET of info/refs, the same commit: still no fetch
        assert outcome.result == "up-to-date" and requests == 1
    finally:
        world.server.close()


def test_a_server_that_keeps_answering_not_modified_cannot_hide_an_expired_timestamp(tmp_path, tls):
    """A freeze: the static copy answers 304 at every check; once the
    timestamp the robot holds has expired, the check is refused as before."""
    world = https_world(tmp_path, tls, smart=False)
    try:
        world.wake()
        world.wake()
        later = NOW + datetime.timedelta(days=400)
        before = world.server.requests
        awake = agent.Wake(world.config, clock=lambda: later)
        _, outcome = awake.run()
        assert world.server.requests - before == 1 and [e["what"] for e in awake.remote.cost.exchanges] == ["probe"]
        assert (outcome.result, outcome.refusal) == ("refused", "expired"), outcome.reason
    finally:
        world.server.close()


def test_an_idle_check_over_ssh_is_one_session_asking_for_the_branch_only(tmp_path):
    world = World(tmp_path)
    key = gitssh.client_key(world.etc)
    server = gitssh.GitSSHServer(world.base, key)
    try:
        (world.etc / "known_hosts").write_text(server.known_hosts(transport.HOST_KEY_ALIAS))
        world.config = agent_files.Config(
            **{**world.config.__dict__, "remote": server.url("fleet.git"), "report_remote": f"file://{world.bare}"}
        )
        world.release(1)
        assert world.wake()[1].result == "applied"
        sessions, server.commands[:] = len(server.sessions), []
        awake = agent.Wake(world.config, clock=lambda: NOW)
        _, outcome = awake.run()
        assert outcome.result == "up-to-date"
        assert len(server.sessions) - sessions == 1 and server.commands == ["ls-refs"]
        assert [e["what"] for e in awake.remote.cost.exchanges] == ["probe"] and awake.remote.cost.received > 0
        # ssh's own count: no algorithm lists a pinned server could not use (robot/ssh_options.py)
        assert awake.remote.cost.sent + awake.remote.cost.received <= 4000, awake.remote.cost.as_dict()
        world.release(2)
        server.commands[:] = []
        assert world.wake()[1].result == "applied"
        assert server.commands[:2] == ["ls-refs", "ls-refs"] and server.commands.count("fetch") == 1
    finally:
        server.close()


def test_a_fetch_cut_before_its_checkout_is_complete_leaves_no_memo(tmp_path):
    """The memo says what the work tree holds: gone from the start of a
    fetch, written only once its checkout is complete."""
    world = World(tmp_path)
    world.release(1)
    world.wake()
    repo = world.state / "releases"
    assert (
        probe.read_memo(repo, world.config.remote, world.config.branch)["commit"]
        == transport.Remote(world.config.remote, repo).fetch_releases()
    )
    world.release(2)
    (repo / ".git" / "index.lock").write_text("")  # the checkout fails, as a cut one would
    with pytest.raises(transport.TransportError):
        transport.Remote(world.config.remote, repo).fetch_releases()
    assert probe.read_memo(repo, world.config.remote, world.config.branch) is None
    (repo / ".git" / "index.lock").unlink()
    assert world.wake()[1].result == "applied"
