"""End to end: pull mode on the simulated fleet (robot1..3 and a robot
booted from a first-boot image), with the lab's git server as the fleet
remote and no SSH from the operator's side once the robots are enrolled.

One lab for the module (the session's, provisioned by push), in order:
release 1 published and the agent installed by a push deploy; robot4
started from a bundle; the robots' sshd turned off.  Then: a robot's key
cannot write another robot's report, nor a shared image's enrollment key an
enrolled robot's (on the lab's real gitolite); release 2 rolled out (publish and
follow reports) reaches every robot, robot3 powered off meanwhile and
catching up at boot; a tampered, a replayed, an expired and a foreign-key
repository are each refused on every robot, which keeps its release; a
crash-looping release is rolled back on the canary and halts the rest;
robot4 reports healthy, is enrolled from its report (host keys, its own key
replacing the enrollment key), proven by its bundle's enrollment key, and
answers SSH with strict host keys; last, the fleet a user writes (the
payload by its tag, no health check) published with publish's defaults goes
from its canary to every robot, one powered off meanwhile.
The robots' timers run at an hour: a robot checks by its own timer at boot
(robot3 and the robot powered off catch up there) and after the agent is
installed, robot4 at its first boot, and otherwise when a test starts its
check (systemctl start), once the release it waits on is on the fleet
remote.  The last release sets the shortest interval (10 s), and its test
waits each robot's next check by its timer.
Releases are reused: release 1 (the only one with wheels), release 2 (the
rollout), the crash-looping one and its halt are the module's publishes;
the bad repositories are made from the current one.  robot4 boots from its
bundle while the others get the agent by push.
"""

from __future__ import annotations

import json
import subprocess
import threading
import time
from pathlib import Path

import pytest

from tests.e2e.conftest import phase, wait_for
from tests.e2e.pullmode import ALL, FIRST_BOOT, ROBOT_GIT_SSH, ROBOTS, Pull, ssh_error

pytestmark = pytest.mark.e2e


@pytest.fixture(scope="module")
def pull(lab, first_run, tmp_path_factory):
    from tests.lab import firstboot

    started = time.monotonic()
    world = Pull(lab, tmp_path_factory.mktemp("pull"))
    op = world.op
    op.setup()
    op.publish(world.fleet("1.0"), "release 1", "--pause", "0")
    world.release1 = world.attacks.checkout()
    phase("pull: keys, release 1 published with wheels", started)
    # robot4 boots from its image now, converging while the others get the agent by push.
    op.robotfleet(
        "bundle", FIRST_BOOT, "--out", str(op.base / "bundle"), "--fleet", world.pullfleet.FLEET, *op.admin_options()
    )
    firstboot.start(lab.prefix, FIRST_BOOT, op.base / "bundle" / "rootfs.tar")
    run = lab.provision(
        *(f"--limit={robot}" for robot in ROBOTS),
        fleet=op.repo / world.pullfleet.FLEET,
        label="(pull agent installed)",
        env={"ROBOTFLEET_KEYS": str(op.keys), "ROBOTFLEET_RELEASES_CLONE": str(op.base / "releases")},
    )
    assert run.returncode == 0, run.output[-4000:]
    env = op.env(ROBOT_LAB_FLEET=str(op.repo / world.pullfleet.FLEET))
    enrolled = op.robotfleet(
        "pull-enroll",
        "inventories/lab.py",
        "--limit",
        ",".join(ROBOTS),
        "--ssh",
        *op.admin_options(),
        *op.remote(),
        env=env,
        check=False,
    )
    assert enrolled.returncode == 0, enrolled.stdout + enrolled.stderr
    for robot in ROBOTS:
        assert f"{robot}: its own key is now registered" in enrolled.stdout, enrolled.stdout + enrolled.stderr
    for robot in ROBOTS:  # from here on the operator's side cannot reach them over SSH
        lab.ok(robot, "systemctl mask --now ssh.service ssh.socket")
        assert ssh_error(lab, robot), robot
    world.trigger(ROBOTS)
    phase("pull: agents installed by push, robots enrolled, sshd off", started)
    yield world
    for robot in ROBOTS:
        lab.sh(
            robot,
            "systemctl disable --now robot-pull.timer; systemctl unmask ssh.service ssh.socket; "
            "systemctl start ssh.service",
        )
    from tests.lab import state
    from tests.lab.engine import client

    client().containers.get(f"{lab.prefix}-{FIRST_BOOT}").remove(force=True)
    saved = state.load(lab.prefix)
    gone = [h["port"] for h in saved["hosts"] if h["name"] == FIRST_BOOT]
    saved["hosts"] = [h for h in saved["hosts"] if h["name"] != FIRST_BOOT]
    state.save(saved)
    known = Path(saved["known_hosts"])  # its keys, from its report: the port may serve another host later
    known.write_text(
        "".join(
            line
            for line in known.read_text().splitlines(keepends=True)
            if not any(line.startswith(f"[127.0.0.1]:{port} ") for port in gone)
        )
    )


# A commit shaped as a robot's report, "$c", made in the robot's releases repository (the server's
# pre-receive hook refuses a report of any other shape); a str.format template, its braces doubled.
REPORT_COMMIT = (
    "cd /var/lib/robot-pull/releases && b=$(printf '{{}}\\n' | git hash-object -w --stdin) && "
    "t=$(printf '100644 blob %s\\treport.json\\n' \"$b\" | git mktree) && c=$(GIT_AUTHOR_NAME=x "
    'GIT_AUTHOR_EMAIL=x@x GIT_COMMITTER_NAME=x GIT_COMMITTER_EMAIL=x@x git commit-tree "$t" -m report) && '
)


def test_a_robot_s_key_writes_only_its_own_report(pull, lab):
    reports = pull.reports()  # each robot wrote its own
    for robot in ROBOTS:  # release 1 applied (a later check of its timer says up-to-date)
        assert reports[robot]["result"] in ("applied", "up-to-date"), reports[robot]
        assert reports[robot]["applied"]["version"] == 1, reports[robot]
    from tests.lab import gitserver

    # a commit the remote does not have yet (an up-to-date push would not be judged), shaped as a report:
    # the server's pre-receive hook refuses any other shape (one with a parent, first: the lab's hook, for real)
    push = REPORT_COMMIT + f'{ROBOT_GIT_SSH}git push --force {gitserver.robot_url(pull.op.git)} "$c:{{ref}}" 2>&1'
    with_parent = push.replace(" -m report)", " -m report -p HEAD)")
    code, output = lab.sh("robot1", with_parent.format(ref="refs/reports/robot1"))
    assert code != 0 and "refs/reports/robot1: a commit with a parent" in output, output
    for ref in ("refs/reports/robot2", "refs/heads/robotfleet/releases"):
        code, output = lab.sh("robot1", push.format(ref=ref))
        assert code != 0 and "DENIED" in output, (ref, output)
    # (its own report ref it writes at every report: the reports read above)


def test_a_shared_image_s_key_reports_only_as_a_name_its_rule_makes_and_no_enrolled_robot(pull, lab):
    """The enrollment key of an image many robots share (`bundle --name-from
    machine-id --name-prefix robot-`), on the lab's real gitolite: it may
    write refs/reports/robot-<12 hex> but neither a registered robot's report
    (one whose name the rule could make, too) nor the releases."""
    from robotfleet.pull.operator import gitolite
    from tests.lab import gitserver

    git = pull.op.git
    admin = gitolite.Admin(f"ssh://{git['user']}@127.0.0.1:{git['port']}", pull.op.lab["ssh_key"], git["known_hosts"])
    shared, enrolled = gitolite.shared_user("machine-id", "robot-"), "robot-0aa0aa0aa0aa"
    lab.ok(
        "robot1",
        "rm -f /tmp/shared /tmp/shared.pub /tmp/other /tmp/other.pub && "
        "ssh-keygen -q -t ed25519 -N '' -f /tmp/shared && ssh-keygen -q -t ed25519 -N '' -f /tmp/other",
    )
    keys = {
        gitolite.key_file(shared): lab.sh("robot1", "cat /tmp/shared.pub")[1],
        gitolite.key_file(enrolled): lab.sh("robot1", "cat /tmp/other.pub")[1],
    }
    gitolite.update(admin, git["repo"], add=keys, message="e2e: a shared image's key, an enrolled robot-<hex>")
    push = REPORT_COMMIT + (
        "GIT_SSH_COMMAND='ssh -F /dev/null -i /tmp/shared -o IdentitiesOnly=yes "
        "-o UserKnownHostsFile=/etc/robot-pull/known_hosts -o HostKeyAlias=robotfleet-remote' "
        f'git push --force {gitserver.robot_url(git)} "$c:{{ref}}" 2>&1'
    )
    try:
        code, output = lab.sh("robot1", push.format(ref="refs/reports/robot-3f2a9c0d1e2b"))
        assert code == 0, output
        for ref in (
            f"refs/reports/{enrolled}",
            "refs/reports/robot2",
            "refs/reports/robot-3f2a9c0d1e2",
            "refs/heads/robotfleet/releases",
        ):
            code, output = lab.sh("robot1", push.format(ref=ref))
            assert code != 0 and "DENIED" in output, (ref, output)
    finally:
        gitolite.update(admin, git["repo"], remove=list(keys), message="e2e: the shared image's keys removed")
        lab.sh("robot1", "rm -f /tmp/shared /tmp/shared.pub /tmp/other /tmp/other.pub")
    # the report it wrote is removed by the admin, as a lost robot's would be
    subprocess.run(
        ["git", "push", "-q", gitserver.local_url(git), ":refs/reports/robot-3f2a9c0d1e2b"],
        env=pull.op.env(),
        check=True,
        capture_output=True,
    )


def test_release_2_reaches_every_robot_without_ssh_and_one_that_was_off_catches_up_at_boot(pull, lab):
    started = time.monotonic()
    from tests.lab.engine import client

    client().containers.get(f"{lab.prefix}-robot3").stop(timeout=20)
    before, result = pull.head(), {}
    follower = threading.Thread(
        target=lambda: result.update(
            done=pull.op.rollout(
                pull.fleet("1.1"),
                "release 2: payload 1.1",
                "--canary",
                "1",
                "--batch",
                "100%",
                "--pause",
                "0",
                "--poll",
                "2",
                "--timeout",
                "420",
                "--publish-option=--no-wheels",
            )
        )
    )
    follower.start()

    def first_boot_robot() -> None:  # its first check (its whole first deploy, from its image) reported first
        first = f"{FIRST_BOOT}'s first release"
        wait_for(lambda: (pull.reports().get(FIRST_BOOT) or {}).get("applied"), 420, first, interval=3)
        pull.trigger_once_published(before, [FIRST_BOOT])

    robot4 = threading.Thread(target=first_boot_robot)
    robot4.start()
    # Published while robot3 was off (the running robots' checks have seen it): robot3 boots and catches
    # up by its own timer (OnBootSec), while the others apply it.
    try:
        pull.trigger_once_published(before, ["robot1", "robot2"])
        seen = {r: ((pull.reports().get(r) or {}).get("seen") or {}).get("version") for r in ("robot1", "robot2")}
    finally:
        client().containers.get(f"{lab.prefix}-robot3").start()
    assert all((version or 0) >= 2 for version in seen.values()), seen
    robot4.join(timeout=500)
    follower.join(timeout=500)
    done = result["done"]
    assert done.returncode == 0, done.stdout + done.stderr
    assert "rollout: [robot3] done" in done.stderr
    for robot in ROBOTS:
        assert lab.version(robot) == "1.1", robot
        assert ssh_error(lab, robot), f"{robot}: its sshd answers"
    pull.trigger(ROBOTS)  # a check after the rollout on each: "up-to-date", whether its last one applied or not
    status = pull.op.status("--limit", "robots", *pull.op.remote())
    for robot in ROBOTS:  # the default table: a pull robot's last report in its ROLLOUT column
        line = next(line for line in status.stdout.splitlines() if line.startswith(robot + " "))
        assert " pull " in line and " healthy " in line, status.stdout
        assert line.endswith(" up-to-date 2"), status.stdout
    phase("pull: release 2 on every robot, robot3 after its boot", started)


@pytest.mark.parametrize(
    "attack, refusal",
    [("tamper", "tampered"), ("replay", "rollback"), ("expire", "expired"), ("other_key", "unknown-key")],
)
def test_a_bad_repository_is_refused_everywhere_and_changes_nothing(pull, lab, attack, refusal):
    good = pull.attacks.checkout()
    before = {r: lab.record(r) for r in ROBOTS}
    if attack == "replay":
        pull.attacks.replay(pull.release1)
    else:
        getattr(pull.attacks, attack)()
    try:
        pull.trigger(ROBOTS)
        reports = pull.reports()
        for robot in ROBOTS:
            assert (reports[robot]["result"], reports[robot]["refusal"]) == ("refused", refusal), reports[robot]
            assert lab.version(robot) == "1.1"
            assert lab.record(robot) == before[robot]
    finally:
        pull.attacks.restore(good)


def test_a_crash_looping_release_is_rolled_back_on_the_canary_and_halts_the_rest(pull, lab):
    from robotfleet.pull.protocol import waves

    started, before = time.monotonic(), pull.head()
    checks = threading.Thread(target=pull.trigger_once_published, args=(before, ROBOTS))  # the canary applies
    checks.start()
    done = pull.op.rollout(
        pull.fleet("1.2-broken", robots=ROBOTS),
        "release: payload 1.2-broken",
        "--canary",
        "1",
        "--batch",
        "100%",
        "--pause",
        "300",
        "--max-failed",
        "0",
        "--poll",
        "2",
        "--timeout",
        "300",
        "--publish-option=--no-wheels",
    )
    checks.join()
    pull.trigger(ROBOTS)  # a check after the halt on each
    assert done.returncode == 1, done.stdout + done.stderr
    assert "halted" in done.stderr
    reports = pull.reports()
    broken = max(r["attempted"]["version"] for r in reports.values() if r.get("attempted"))
    canary = waves.rank(ROBOTS, broken)[0]
    assert reports[canary]["attempted"]["result"] == "rolled-back", reports[canary]
    for robot in ROBOTS:
        assert lab.version(robot) == "1.1", robot
        assert lab.payload(robot)["State"]["Health"]["Status"] == "healthy"
        if robot != canary:
            assert reports[robot]["result"] == "halted", reports[robot]
            assert (reports[robot]["applied"] or {}).get("version") != broken
    phase("pull: crash-looping release rolled back on the canary, the rest halted", started)


def test_a_robot_from_a_first_boot_image_converges_reports_healthy_and_is_enrolled_from_its_report(pull, lab):
    started = time.monotonic()
    wait_for(lambda: (pull.reports().get(FIRST_BOOT) or {}).get("applied"), 420, f"{FIRST_BOOT}'s first release")
    op = pull.op
    op.commit(pull.fleet("1.1"), "the fleet with robot4 again")  # the crash-looping release was for robot1..3
    env = op.env(ROBOT_LAB_FLEET=str(op.repo / pull.pullfleet.FLEET))
    assert ssh_error(lab, FIRST_BOOT)  # not in known_hosts yet: no trust on first use
    enrolled = op.robotfleet(
        "pull-enroll", "inventories/lab.py", "--limit", FIRST_BOOT, *op.admin_options(), *op.remote(), env=env
    )
    assert f"{FIRST_BOOT}: its report is proven by its bundle's enrollment key" in enrolled.stdout, enrolled.stdout
    assert "from its report; enrolled" in enrolled.stdout and "its own key is now registered" in enrolled.stdout
    assert ssh_error(lab, FIRST_BOOT) is None  # strict host keys: the key from its report
    pull.trigger([FIRST_BOOT])
    assert lab.sh(FIRST_BOOT, "test -e /etc/robot-pull/enroll_ed25519")[0] != 0  # retired once its own key worked
    # the newest release is the halt the crash-looping rollout published (the test above): a halt stops
    # every robot whatever the release it halts named (decide.py), and a halted check leaves no idle memo
    report = pull.reports()[FIRST_BOOT]
    assert report["result"] == "halted", report
    status = op.status("--limit", FIRST_BOOT, *op.remote())
    line = next(line for line in status.stdout.splitlines() if line.startswith(FIRST_BOOT + " "))
    assert " pull " in line and " healthy " in line, status.stdout
    phase("pull: first-boot robot enrolled from its report", started)


# publish's default pause is the robots' longest pull_interval + pull_jitter
# (the role's 900 + 300 s: the canary's whole check period).  This test checks
# that the canary applies before the rest: every running robot checks as soon
# as the release is published, the canary applies and the rest are held until
# wave 1 opens, when they check again.  The pause needs to outlast only the
# time from publish to the rest's first decision (seconds), not the canary's
# apply (a check started once the pause is over waits for the canary's first).
CANARY_PAUSE = 60


def user_fleet(pull, image: str) -> str:
    """The fleet a user writes from docs/guides/pull.md: the payload by its tag in
    all.vars (no digest: publish resolves it), payload_stable_seconds 5 and
    the pull settings in robots' vars, the shortest check interval (10 s: the
    robots' timers tested); robot1..4."""
    fleet = json.loads(pull.fleet("1.1").split("\n", 1)[1])
    fleet["all"]["vars"].update(payload_image=image, payload_stable_seconds=5)
    fleet["robots"]["vars"].pop("payload_stable_seconds")
    fleet["robots"]["vars"]["pull_interval"] = 10
    return "# The lab's fleet as a user writes it (tests/e2e/test_pull.py).\n" + json.dumps(fleet, indent=1) + "\n"


def test_a_release_published_with_the_defaults_goes_from_its_canary_to_every_robot(pull, lab):
    """Issue 35: a payload named by its tag in all.vars and without a health
    check (ros/driver), published with publish's defaults: a canary, then
    the rest, a failure budget of 0 (only the pause set: see CANARY_PAUSE).  Every robot
    applies it, one powered off while it was published and robot4, booted
    from its first-boot image, included; status exits 0 and its IMAGE keeps
    the tag.  The module's other releases name their image with its digest
    in the fleet file, which hid a converge that judged the robot against
    the fleet file's tag instead of the digest the release pinned."""
    from robotfleet.pull.operator.repository import Repository
    from robotfleet.pull.protocol import waves
    from tests.lab.engine import client
    from tests.lab.registryproxy import RegistryProxy

    started, op = time.monotonic(), pull.op
    # robot4 runs what its image brought first (its whole first deploy: minutes), then takes this release
    wait_for(lambda: (pull.reports().get(FIRST_BOOT) or {}).get("applied"), 600, f"{FIRST_BOOT}'s first release")
    registry = op.lab["registry"]
    image = f"{registry}/ros/driver:1.1"
    version = Repository(op.base / "releases").record().version + 1
    canary = waves.rank(ALL, version)[0]
    off = next(robot for robot in ROBOTS if robot != canary)
    on = [robot for robot in ALL if robot != off]
    rest = [robot for robot in on if robot != canary]
    client().containers.get(f"{lab.prefix}-{off}").stop(timeout=20)
    try:
        op.commit(user_fleet(pull, image), f"release {version}: ros/driver:1.1 by its tag")
        # publish reads the digest from the registry by the robots' name for it
        proxy = RegistryProxy(registry, op.lab["registry_local"])
        try:
            done = op.robotfleet(
                "publish",
                pull.pullfleet.FLEET,
                "--checkout",
                str(op.repo),
                "--keys",
                str(op.keys),
                "--no-wheels",
                "--pause",
                str(CANARY_PAUSE),
                env=op.env(**proxy.env()),
            )
        finally:
            proxy.close()
        assert f"publish: release {version} (" in done.stdout, done.stdout
        assert f"wave(s); wave k opens at publish + k x {CANARY_PAUSE} s" in done.stdout, done.stdout
        assert f"GET http://{registry}/v2/ros/driver/manifests/1.1" in proxy.requests
        published = time.monotonic()  # the record's published_at is earlier

        def applied(robots) -> bool:
            reports = pull.reports()
            return all(
                (reports.get(r) or {}).get("result") in ("applied", "up-to-date")
                and ((reports.get(r) or {}).get("applied") or {}).get("version") == version
                for r in robots
            )

        pull.trigger(on)  # every running robot checks now: the canary applies, the rest are held
        reports = pull.reports()
        assert applied([canary]), reports[canary]
        for robot in rest:  # (while held, a robot prefetches the release's image)
            report = reports[robot]
            assert report["result"] in ("waiting", "prefetched"), report
            assert "waiting for wave 1" in report["reason"] and report["applied"]["version"] < version, report
        time.sleep(max(0.0, published + CANARY_PAUSE + 1 - time.monotonic()))
        pull.trigger(rest)  # wave 1 open
        assert applied(on), pull.reports()
    finally:
        client().containers.get(f"{lab.prefix}-{off}").start()  # it boots, and catches up by its own timer
    wait_for(lambda: applied([off]), 300, f"release {version} on {off} after its boot", interval=3)
    reports = pull.reports()
    first = reports[canary]["applied"]["time"]
    assert all(first < reports[r]["applied"]["time"] for r in ALL if r != canary), reports  # canary, then the rest
    # each robot's next check by its timer (10 s on, the release's interval) finds the release it applied:
    # from then on its report says up-to-date
    wait_for(
        lambda: all(pull.reports()[r]["result"] == "up-to-date" for r in ALL),
        60,
        "every robot's next check",
        interval=3,
    )
    status = op.status("--limit", ",".join(ALL), "-o", "wide", *op.remote())
    assert status.returncode == 0, status.stdout + status.stderr
    for robot in ALL:  # -o wide: IMAGE, and PULL beside REPORTED
        line = next(line for line in status.stdout.splitlines() if line.startswith(robot + " "))
        assert f" {image}@sha256:" in line and " no check " in line, status.stdout  # the tag kept
        assert f" up-to-date {version} " in line, status.stdout
    phase(f"pull: release {version} by publish's defaults on every robot, {off} after its boot", started)


def test_sharded_reports_reach_the_operator_through_the_git_server_s_read_copy(pull, lab, tmp_path, monkeypatch):
    """The lab's gitolite has the read-copy hook as docs/guides/pull.md installs
    it (its common hooks).  With the rules for two report shards, robot1
    pushes its report with its own key to its own shard and is refused
    another's; the hook copies it into the fleet remote's refs/report-copy,
    and the operator's read (what `robotfleet status` runs) takes it from
    there, fetching no shard."""
    from robotfleet.pull.operator import gitolite
    from robotfleet.pull.protocol import report_shards, report_store
    from tests.lab import gitserver
    from tests.lab.engine import client

    git, shards = pull.op.git, 2
    admin = gitserver.admin(git, lab.state["ssh_key"])
    gitolite.update(admin, git["repo"], message="e2e: two report shards", shards=shards)
    try:
        own, url = report_shards.shard_of("robot1", shards), gitserver.robot_url(git)
        ssh = ROBOT_GIT_SSH
        push = (  # its last report, from the fleet remote, into a shard (the report's blob printed last)
            f"d=$(mktemp -d) && git init -q $d && cd $d && {ssh}git fetch -q {url} refs/reports/robot1 && "
            f"{ssh}git push --force {{shard}} FETCH_HEAD:refs/reports/robot1 2>&1 && "
            "git rev-parse FETCH_HEAD:report.json; c=$?; rm -rf $d; exit $c"
        )
        code, output = lab.sh("robot1", push.format(shard=report_shards.shard_url(url, 1 - own)))
        assert code != 0 and "DENIED" in output, output
        code, output = lab.sh("robot1", push.format(shard=report_shards.shard_url(url, own)))
        assert code == 0, output
        server = client().containers.get(git["container"])
        code, listed = server.exec_run(
            [
                "git",
                "-C",
                f"{gitserver.HOME}/repositories/{git['repo']}.git",
                "ls-tree",
                "-r",
                "--name-only",
                report_store.COPY,
            ],
            user=gitserver.USER,
        )
        assert code == 0 and listed.decode().split() == [f"{own}/robot1"], listed
        code, blob = server.exec_run(
            [
                "git",
                "-C",
                f"{gitserver.HOME}/repositories/{git['repo']}.git",
                "rev-parse",
                f"{report_store.COPY}:{own}/robot1",
            ],
            user=gitserver.USER,
        )
        assert blob.decode().strip() == output.split()[-1]  # the report robot1 pushed, copied
        monkeypatch.setenv("GIT_SSH_COMMAND", pull.op.env()["GIT_SSH_COMMAND"])
        found = report_store.fetch_every(gitserver.local_url(git), shards, tmp_path / "reports")
        copied = report_store.read_copy(tmp_path / "reports", report_store.COPY, shards)
        assert "error" not in copied["robot1"] and copied["robot1"]["robot"] == "robot1", copied
        # its timer may have reported since, to the fleet remote (its agent has no shards): the newer one read
        assert found["robot1"]["time"] >= copied["robot1"]["time"]
        assert not (tmp_path / "reports-shards").exists()  # the copy read, no shard fetched
    finally:
        gitolite.update(admin, git["repo"], message="e2e: the reports in one repository again")
