"""Commands that tell the truth (issue 18, items 2 and 5): a --limit that
matches nothing, a dry rollout whose robots are unreachable, any command
that did nothing it was asked to do exits non-zero with one line; status
tells as each host answers and carries each host's reason; a rollout targets
robots and tries an unreachable robot once per wave.  Real sockets on
127.0.0.1 (a listener that never speaks, a closed port)."""

from __future__ import annotations

import json
import time

import pytest

from tests.fixtures import PYINFRA, ROOT, pyinfra
from tests.integration import sshserver
from tests.integration.operator_side import fleet, run


@pytest.fixture(autouse=True)
def key(client_key):
    return client_key


def test_a_limit_that_matches_nothing_is_refused_by_every_command(tmp_path):
    path = fleet(tmp_path, {"robot1": {"address": "127.0.0.1"}})
    line = (
        "--limit bot-z: no host or group of inventories/robots.py matches (hosts: robot1; groups: robots); "
        "nothing was done"
    )
    for argv in (
        ["-c", PYINFRA, "-y", "inventories/robots.py", "deploy.py", "--limit", "bot-z"],
        ["-m", "robotfleet", "status", "inventories/robots.py", "--limit", "bot-z"],
        ["-m", "robotfleet", "rollout", "inventories/robots.py", "--limit", "bot-z", "--dry"],
        ["-m", "robotfleet", "enroll", "inventories/robots.py", "--limit", "bot-z"],
    ):
        result = run(path, tmp_path, *argv)
        ours = [x for x in result.stderr.splitlines() if not x.startswith("--> ")]
        assert (result.returncode, ours) == (2, [line]), (argv, result.stderr)


def test_status_tells_as_hosts_answer_and_each_reason(tmp_path):
    with sshserver.wrong_hosts() as (silent, closed):
        path = fleet(
            tmp_path,
            {
                "robot1": {"address": "127.0.0.1", "ssh_port": silent.port},
                "robot2": {"address": "127.0.0.1", "ssh_port": closed},
            },
            ssh_connect_retries=0,
        )
        started = time.monotonic()
        result = run(path, tmp_path, "-m", "robotfleet", "status", "inventories/robots.py", "--json")
        elapsed = time.monotonic() - started
    assert result.returncode == 3, result.stderr
    refused = f"connection refused by 127.0.0.1:{closed} (no SSH server listens on port {closed})"
    silent_reason = (
        f"no SSH greeting: 127.0.0.1:{silent.port} accepted the connection but sent nothing "
        "within 2 s: a link that stalls (Wi-Fi, LTE), or not an SSH server (wrong port?)"
    )
    assert result.stderr.splitlines() == [
        f"[robot2] unreachable: {refused} (1/2)",
        f"[robot1] unreachable: {silent_reason} (2/2)",
    ]
    rows = {row["host"]: row for row in json.loads(result.stdout)}
    assert (rows["robot1"]["error"], rows["robot2"]["error"]) == (silent_reason, refused)
    assert elapsed < 20, elapsed


def test_a_dry_rollout_over_unreachable_robots_is_not_a_success(tmp_path):
    closed = sshserver.closed_port()
    path = fleet(tmp_path, {"robot1": {"address": "127.0.0.1", "ssh_port": closed}}, ssh_connect_retries=0)
    result = run(path, tmp_path, "-m", "robotfleet", "rollout", "inventories/robots.py", "--dry")
    assert result.returncode == 3, result.stderr
    assert "rollout: dry run incomplete: 1 robot(s) unreachable, not planned: robot1" in result.stderr.splitlines()


def test_a_rollout_targets_robots_and_tries_a_dead_one_once_per_wave(tmp_path):
    silent = sshserver.Listener()
    try:
        path = tmp_path / "fleet.yaml"
        fleet(tmp_path, {"robot1": {"address": "127.0.0.1", "ssh_port": silent.port}}, ssh_connect_retries=0)
        text = (
            path.read_text() + "laptops:\n  hosts:\n    laptop1: {address: 127.0.0.1, ssh_port: 9, x11_user: alice}\n"
        )
        path.write_text(text)
        result = run(path, tmp_path, "-m", "robotfleet", "rollout", "inventories/robots.py", "-y")
    finally:
        silent.close()
    assert result.returncode == 3, result.stderr
    waves = [line for line in result.stderr.splitlines() if line.startswith(("wave ", "--> wave"))]
    assert waves[0] == "wave 1/1: robot1 (unreachable now: robot1)" and "laptop1" not in result.stdout + result.stderr
    assert "rollout: [robot1] skipped: unreachable: " in result.stderr
    # once before the waves (the status of every robot at once), once in its wave
    assert silent.connections == 2


@pytest.mark.parametrize("inventory", ["robots.py", "local.py"])
def test_pyinfra_from_outside_the_checkout_is_refused_before_any_connection(tmp_path, inventory):
    """Run elsewhere, pyinfra would drop config.py and group_data/ (strict
    host-key checking among them) without a word (issue 27, item 3)."""
    path = fleet(tmp_path, {"robot1": {"address": "127.0.0.1", "ssh_port": 1}})
    env = {
        "PATH": "/usr/bin:/bin",
        "ROBOT_FLEET": str(path),
        "PYINFRA_PROGRESS": "off",
        "HOME": str(tmp_path),
        "ROBOT_FLEET_HOST": "robot1",
    }
    result = pyinfra("-y", str(ROOT / "inventories" / inventory), str(ROOT / "deploy.py"), cwd=tmp_path, env=env)
    assert result.returncode == 2, result.stderr[-2000:]
    assert result.stderr.strip().splitlines()[-1] == (
        f"pyinfra runs in {tmp_path}, not in the checkout {ROOT}: its config.py and group_data/ (strict host-key "
        f"checking, sudo, every default) would not apply; run it there: cd {ROOT}, or pyinfra --chdir {ROOT} ..."
    )
    assert not (tmp_path / ".ssh").exists()  # no key accepted on first use


@pytest.mark.parametrize("typed", ["0", "-3", "ten", ""])
def test_parallel_is_a_number_of_hosts_one_or_more(tmp_path, typed):
    path = fleet(tmp_path, {"robot1": {"address": "127.0.0.1"}})
    for command in ("status", "rollout"):
        result = run(path, tmp_path, "-m", "robotfleet", command, "inventories/robots.py", "--parallel", typed)
        assert result.returncode == 2, result.stderr[-1000:]
        assert f"--parallel: {typed!r}: a number of hosts, 1 or more" in result.stderr


# --- every command's exit codes, README's one table (issue 39 items 8 and 9) ---


def test_a_mistyped_deploy_file_is_pyinfras_exit_1_before_any_host_is_contacted(tmp_path):
    """pyinfra checks its deploy files before it loads the inventory (robotfleet's code): README's table says
    so, as it is."""
    silent = sshserver.Listener()
    try:
        path = fleet(tmp_path, {"robot1": {"address": "127.0.0.1", "ssh_port": silent.port}}, ssh_connect_retries=0)
        result = run(path, tmp_path, "-c", PYINFRA, "-y", "inventories/robots.py", "deplyo.py")
        assert silent.connections == 0
    finally:
        silent.close()
    assert (result.returncode, result.stderr.strip()) == (1, "--> pyinfra error: No deploy file: deplyo.py")


def test_pull_enroll_and_bundle_refuse_a_robot_that_does_not_pull(tmp_path):
    path = fleet(tmp_path, {"robot1": {"address": "127.0.0.1"}})
    result = run(path, tmp_path, "-m", "robotfleet", "pull-enroll", "inventories/robots.py")
    assert (result.returncode, result.stderr) == (
        2,
        "inventories/robots.py: no pull robot (pull_enabled: true) to enroll\n",
    )
    result = run(path, tmp_path, "-m", "robotfleet", "bundle", "robot1", "--out", str(tmp_path / "b"))
    assert result.returncode == 2 and result.stderr.startswith("bundle: ")
    assert "robot1 is not a pull robot" in result.stderr
    assert not (tmp_path / "b").exists()


def test_generate_check_is_0_when_current_and_2_for_bad_arguments(tmp_path):
    path = fleet(tmp_path, {"robot1": {"address": "127.0.0.1"}})
    assert run(path, tmp_path, "-m", "robotfleet", "generate", "--check").returncode == 0
    assert run(path, tmp_path, "-m", "robotfleet", "generate", "--chek").returncode == 2


def test_every_limit_has_one_help_and_every_summary_is_a_sentence(tmp_path):
    from robotfleet import commands

    path = fleet(tmp_path, {"robot1": {"address": "127.0.0.1"}})
    for command in ("status", "rollout", "enroll", "pull-enroll"):
        shown = " ".join(run(path, tmp_path, "-m", "robotfleet", command, "--help").stdout.split())
        assert f"--limit LIMIT {commands.LIMIT_HELP}" in shown, (command, shown)
    listed = run(path, tmp_path, "-m", "robotfleet", "--help").stdout.split("commands:\n", 1)[1].split("\n\n", 1)[0]
    assert all(line.rstrip().endswith(".") for line in listed.splitlines()), listed
