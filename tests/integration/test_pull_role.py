"""The pull role: its settings' checks, the agent's configuration and units
it renders, and the commands it plans (pyinfra @fake with a canned snapshot)."""

from __future__ import annotations

import base64
import io
import json
import subprocess
import tarfile

import pytest

import roles.pull as pull_role
import roles.pull.plan as plan
from robotfleet.pull.operator import install
from robotfleet.pull.protocol import agent_files
from roles.payload import installed_files
from tests.unit import pullkit
from tests.unit.harness import ROBOT, converged, find, fleet_problems, fresh_host, merged, written_files
from tests.unit.harness import plan as run_plan
from tests.unit.pullkit import NOW

KEY = "ssh-ed25519 AAAAC3NzaC1lZDI1NTE5AAAAIGbigA6mqsYKDD3V4SGhrWodxIaju5HYfXtBYAQEvqW0"
WHEEL = "gevent-25.5-cp313-cp313-manylinux_2_28_x86_64.whl"
ARM_WHEEL = "gevent-25.5-cp311-cp311-manylinux_2_28_aarch64.whl"


def publish_with_wheels(fleet, version: int, wheels: dict[str, dict[str, bytes]]):
    """Release ``version`` carrying ``wheels`` (platform -> file name -> content)."""
    record, waves = pullkit.module("protocol.record"), pullkit.module("protocol.waves")
    files, listed = {}, {}
    for platform, named in wheels.items():
        listed[platform] = []
        for name, content in named.items():
            local = fleet.base / f"{platform}-{name}"
            local.write_bytes(content)
            files[f"wheels/{name}"] = local
            listed[platform].append(f"wheels/{name}")
    built = record.build(
        version,
        NOW,
        NOW + fleet.expiry.targets,
        "a" * 40,
        "b" * 64,
        "inventories/robots.yaml",
        "c" * 64,
        ["r1"],
        {},
        listed,
        waves.Plan(),
    )
    code = fleet.base / f"code-{version}.tar.gz"
    code.write_bytes(b"code")
    fleet.repository.publish(built, {built.code: code, **files}, fleet.keys.signer("online"), fleet.expiry, NOW)
    install.wheel_set.cache_clear()


@pytest.fixture
def released(tmp_path, monkeypatch):
    """The operator's keys and release repository (as robotfleet publish leaves them), release 1 with wheels."""
    fleet = pullkit.Fleet(tmp_path)
    publish_with_wheels(
        fleet, 1, {"cp313-x86_64": {WHEEL: b"cp313-x86_64"}, "cp311-aarch64": {ARM_WHEEL: b"cp311-aarch64"}}
    )
    monkeypatch.setenv("ROBOTFLEET_RELEASES_CLONE", str(fleet.repository.path))
    monkeypatch.setenv("ROBOTFLEET_KEYS", str(tmp_path / "keys"))
    return fleet


@pytest.fixture
def pulled(released):
    """Robot data in pull mode."""
    return {
        **ROBOT,
        "pull_enabled": True,
        "pull_remote": "ssh://gitolite3@git.lan/fleet",
        "pull_remote_host_keys": [KEY],
        "pull_interval": 60,
        "pull_jitter": 5,
    }


def robot(**extra):
    return {"robots": {"hosts": {"robot3": {"payload_image": "reg.example.com/ros/payload:1.0", **extra}}}}


@pytest.mark.parametrize(
    "doc, expected",
    [
        (
            robot(pull_enabled=True),
            "robots.yaml: robot3.pull_remote: required when pull_enabled is true: the git URL of "
            "the fleet remote (e.g. ssh://gitolite3@git.example.com/fleet)",
        ),
        (
            robot(pull_enabled=True, pull_remote="ssh://git@git.lan/fleet"),
            "robots.yaml: robot3.pull_remote_host_keys: required for an ssh remote: the git server's host keys "
            "(ssh-keyscan HOST, checked against the server's own)",
        ),
        (
            robot(pull_remote="ssh://git@git.lan/fleet;reboot"),
            "robots.yaml: robot3.pull_remote: expected a git URL: ssh://user@host[:port]/path, user@host:path or "
            "https://host/path, got 'ssh://git@git.lan/fleet;reboot'",
        ),
        (
            robot(pull_remote="-oProxyCommand=x"),
            "robots.yaml: robot3.pull_remote: expected a git URL: ssh://user@host[:port]/path, user@host:path or "
            "https://host/path, got '-oProxyCommand=x'",
        ),
        (
            robot(pull_remote_host_keys=["git.lan ssh-ed25519 AAAA"]),
            "robots.yaml: robot3.pull_remote_host_keys[0]: expected a public host key like 'ssh-ed25519 AAAA...' "
            "(ssh-keyscan's line without the host), got 'git.lan ssh-ed25519 AAAA'",
        ),
        (robot(pull_interval=5), "robots.yaml: robot3.pull_interval: expected at least 10, got 5"),
        (
            robot(pull_windows=["weekdays 01:00-05:00"]),
            "robots.yaml: robot3.pull_windows[0]: expected a maintenance window like 'Mon-Fri 01:00-05:00' or "
            "'daily 22:00-02:00 UTC', got 'weekdays 01:00-05:00'",
        ),
        (
            robot(pull_windows=["daily 01:00-01:00"]),
            "robots.yaml: robot3.pull_windows[0]: maintenance window 'daily 01:00-01:00': starts and ends at the same "
            "time; for all day write 00:00-23:59",
        ),
        (robot(pull_enabled="yes"), "robots.yaml: robot3.pull_enabled: expected true or false, got 'yes'"),
        (
            robot(pull_enabled=True, pull_remote="https://git.lan/fleet", pull_report_remote="ssh://git@git.lan/fleet"),
            "robots.yaml: robot3.pull_remote_host_keys: required for an ssh remote: the git server's host keys "
            "(ssh-keyscan HOST, checked against the server's own)",
        ),
        (
            robot(pull_enabled=True, pull_remote="https://git.lan/fleet", pull_platform="cp38-x86_64"),
            "robots.yaml: robot3.pull_platform: cp38-x86_64: a robot's python3 3.8 is too old for pull mode (the "
            "robot runs pyinfra 3, which needs Python 3.10 or later): provision it by push (pull_enabled: false), "
            "or give it a python3 of 3.10 or later",
        ),
    ],
)
def test_bad_pull_settings_get_one_clear_line(doc, expected):
    assert fleet_problems(doc) == [expected]


@pytest.mark.parametrize(
    "extra",
    [
        {"pull_enabled": True, "pull_remote": "ssh://gitolite3@git.lan:2222/fleet", "pull_remote_host_keys": [KEY]},
        {"pull_enabled": True, "pull_remote": "git@git.lan:robots/fleet.git", "pull_remote_host_keys": [KEY]},
        {"pull_enabled": True, "pull_remote": "https://git.lan/robots/fleet.git"},
        {
            "pull_enabled": True,
            "pull_remote": "https://mirror.lan/fleet.git",
            "pull_report_remote": "ssh://gitolite3@git.lan/fleet",
            "pull_remote_host_keys": [KEY],
            "pull_remote_ca": "files/fleet-ca.pem",
        },
        {"pull_windows": ["Mon-Fri 01:00-05:00", "Sat,Sun 00:00-23:59 UTC"]},
        {"pull_remote": "ssh://git@10.20.0.5/fleet"},  # set for the fleet; used where pull_enabled is true
        {"pull_enabled": True, "pull_remote": "https://git.lan/fleet", "pull_platform": "cp310-x86_64"},
        {"pull_platform": "cp38-x86_64"},  # a robot provisioned by push
    ],
)
def test_good_pull_settings_are_accepted(extra):
    assert fleet_problems(robot(**extra)) == []


def test_the_role_is_opt_in():
    result = run_plan({"r1": ("robots", ROBOT, fresh_host("debian-13"))})
    assert pull_role.INSTALLED_PROBE not in result.queries["r1"]["probes"]
    assert not find(result["r1"], "robot-pull")


def test_agent_configuration_and_units(pulled):
    data = merged("robots", {**pulled, "pull_windows": ["Mon-Fri 01:00-05:00"]})
    config = agent_files.read_config(agent_files.for_host(data, "robot7").to_json())
    assert config.robot == "robot7" and config.remote == "ssh://gitolite3@git.lan/fleet"
    assert (config.interval, config.jitter, config.windows) == (60, 5, ("Mon-Fri 01:00-05:00",))
    timer = agent_files.timer_unit(data)
    for line in (
        "OnBootSec=60",
        "OnUnitInactiveSec=60",
        "RandomizedDelaySec=5",
        "Persistent=true",
        "WantedBy=timers.target",
    ):
        assert f"\n{line}\n" in timer
    service = agent_files.service_unit()
    assert "\nType=oneshot\n" in service and "\nUser=" not in service
    assert (
        f"\nExecStart={agent_files.VENV}/bin/python -m robotfleet.pull.agent --config {agent_files.CONFIG}\n" in service
    )
    assert agent_files.known_hosts(data) == f"{agent_files.HOST_KEY_ALIAS} {KEY}\n"


def test_a_fresh_robot_gets_the_agent(pulled, released):
    result = run_plan({"r1": ("robots", pulled, fresh_host("debian-13"))})
    commands = result["r1"]
    assert result.failed == set()
    assert find(commands, r"install python3-venv git openssh-client")
    files = written_files(commands)
    config = json.loads(files[agent_files.CONFIG])
    # The images the agent puts in place go through the role that runs them (robotfleet.role Role.image_helper).
    assert config["robot"] == "@fake/r1" and config["extra"]["image_helper"] == [installed_files.HELPER]
    assert files[agent_files.TRUST_ROOT] == (released.repository.metadata / "root.json").read_text()
    assert files[f"{agent_files.UNIT_DIR}/{agent_files.TIMER}"] == agent_files.timer_unit(merged("robots", pulled))
    for path in (agent_files.CONFIG, agent_files.TRUST_ROOT):
        assert "chmod 600" in find(commands, f"dest={path}\n")[0]
    keygen = find(commands, "ssh-keygen -q -t ed25519")
    assert len(keygen) == 1 and f'mv -T "$tmp/key" {agent_files.KEY}' in keygen[0]
    # The wheels of the robot's python (Debian 13: 3.13) and architecture, as one archive.
    venv = find(commands, "python3 -m venv")
    assert len(venv) == 1
    sent = tarfile.open(fileobj=io.BytesIO(base64.b64decode(venv[0].stdin)))
    assert sent.getnames() == [WHEEL]
    assert sent.extractfile(WHEEL).read() == b"cp313-x86_64"
    code = find(commands, r"tar -xz -C")
    assert len(code) == 1
    tree = tarfile.open(fileobj=io.BytesIO(base64.b64decode(code[0].stdin)))
    assert {"deploy.py", "robotfleet/role.py", "roles/payload/__init__.py", "inventories/robots.yaml"} <= set(
        tree.getnames()
    )
    assert not [n for n in tree.getnames() if n.startswith(("tests/", "docs/")) or "__pycache__" in n]
    assert find(commands, "systemctl enable robot-pull.timer")


def test_an_arm64_robot_gets_its_own_wheels(pulled):
    snap = fresh_host("debian-12", arch="arm64")
    snap.probes[pull_role.PYTHON_PROBE] = "311\n"
    commands = run_plan({"r1": ("robots", {**pulled, "pull_platform": "cp311-aarch64"}, snap)})["r1"]
    sent = tarfile.open(fileobj=io.BytesIO(base64.b64decode(find(commands, "python3 -m venv")[0].stdin)))
    assert sent.extractfile(sent.getnames()[0]).read() == b"cp311-aarch64"


def test_a_robot_that_is_not_its_pull_platform_is_refused_in_one_line(pulled):
    result = run_plan({"r1": ("robots", pulled, fresh_host("ubuntu-22.04"))})
    assert result.failed == {"r1"}
    assert find(
        result["r1"], "pull_platform: cp313-x86_64, but this robot runs cp310-x86_64; .*set pull_platform: cp310-x86_64"
    )


@pytest.mark.parametrize("probed", ["38\n", ""])  # Ubuntu 20.04's python3, or none yet (apt would bring 3.8)
def test_a_robot_whose_python_is_too_old_for_pull_mode_is_refused_before_anything_changes(pulled, probed):
    snap = fresh_host("ubuntu-20.04")
    snap.probes[pull_role.PYTHON_PROBE] = probed
    result = run_plan({"r1": ("robots", {**pulled, "pull_platform": "cp310-x86_64"}, snap)})
    assert result.failed == {"r1"}
    line = (
        "this robot's python3 3.8 is too old for pull mode (the robot runs pyinfra 3, which needs Python 3.10 "
        "or later): provision it by push (pull_enabled: false), or give it a python3 of 3.10 or later"
    )
    assert len(result["r1"]) == 1  # the refusal, and nothing of any role before it
    said = subprocess.run(result["r1"][0], shell=True, capture_output=True, text=True)  # it only echoes
    assert (said.returncode, said.stderr) == (1, line + "\n")
    pushed = run_plan({"r1": ("robots", {**pulled, "pull_enabled": False}, snap)})
    assert pushed.failed == set() and len(pushed["r1"]) > 10  # the way out: push mode provisions it


def test_a_platform_the_release_carries_no_wheels_for_is_refused_in_one_line(pulled):
    snap = fresh_host("ubuntu-22.04")
    result = run_plan({"r1": ("robots", {**pulled, "pull_platform": "cp310-x86_64"}, snap)})
    assert result.failed == {"r1"}
    assert find(result["r1"], "release 1 carries no wheels for cp310-x86_64")


def test_converged_robot_plans_nothing(pulled):
    snap = converged("robots", pulled, "debian-13")
    result = run_plan({"r1": ("robots", pulled, snap)})
    assert result.failed == set()
    assert result["r1"] == []


def test_the_wheels_of_a_new_release_make_a_new_venv_and_nothing_else(pulled, released):
    snap = converged("robots", pulled, "debian-13")
    publish_with_wheels(released, 2, {"cp313-x86_64": {WHEEL: b"cp313-x86_64", "jinja2-3.1-py3-none-any.whl": b"j"}})
    commands = run_plan({"r1": ("robots", pulled, snap)})["r1"]
    assert len(commands) == 1 and "python3 -m venv" in commands[0]


def test_the_agent_running_the_deploy_keeps_the_release_s_venv_and_tree(pulled):
    snap = converged("robots", pulled, "debian-13")
    snap.probes[pull_role.INSTALLED_PROBE] = "venv=venvs/0123456789abcdef\ncode=feedface\n"
    assert len(run_plan({"r1": ("robots", pulled, snap)})["r1"]) == 2
    commands = run_plan({"r1": ("robots", {**pulled, pull_role.AGENT_RUN: {"version": 7}}, snap)})["r1"]
    assert commands == []


def test_an_existing_key_is_kept_and_a_changed_interval_restarts_the_timer(pulled):
    snap = converged("robots", pulled, "debian-13")
    commands = run_plan({"r1": ("robots", {**pulled, "pull_interval": 120}, snap)})["r1"]
    assert not find(commands, "ssh-keygen")
    assert set(written_files(commands)) == {agent_files.CONFIG, f"{agent_files.UNIT_DIR}/{agent_files.TIMER}"}
    assert find(commands, "systemctl daemon-reload") and find(commands, "systemctl restart robot-pull.timer")


def test_a_missing_trust_root_fails_the_host_naming_the_file(pulled, tmp_path):
    result = run_plan(
        {"r1": ("robots", {**pulled, "pull_trust_root": str(tmp_path / "nope.json")}, fresh_host("debian-13"))}
    )
    assert result.failed == {"r1"}
    assert find(result["r1"], "pull_trust_root: .*nope.json cannot be read")


def test_a_trust_root_that_is_not_the_operator_s_is_refused(pulled, tmp_path):
    other = pullkit.Fleet(tmp_path / "other")
    theirs = str(other.repository.metadata / "root.json")
    result = run_plan({"r1": ("robots", {**pulled, "pull_trust_root": theirs}, fresh_host("debian-13"))})
    assert result.failed == {"r1"}
    assert find(result["r1"], "signed by none of the root keys in .*keys")
    pullkit.edit_json(other.repository.metadata / "root.json", lambda d: d["signed"].update(version=5))
    with pytest.raises(install.InstallError, match="is not a TUF root signed by its own keys"):
        install.trust_root(tmp_path, theirs)


def test_an_https_remote_s_ca_is_installed_and_removed_when_unset(pulled, tmp_path):
    from tests.integration import httpsgit

    ca = httpsgit.make_ca(tmp_path / "tls")[0]
    https = {**pulled, "pull_remote": "https://127.0.0.1:8443/fleet.git", "pull_remote_ca": str(ca)}
    files = written_files(run_plan({"r1": ("robots", https, fresh_host("debian-13"))})["r1"])
    assert files[agent_files.REMOTE_CA] == ca.read_text()
    assert json.loads(files[agent_files.CONFIG])["remote"] == "https://127.0.0.1:8443/fleet.git"
    snap = converged("robots", https, "debian-13")
    assert not written_files(run_plan({"r1": ("robots", https, snap)})["r1"])  # converged: nothing
    commands = run_plan({"r1": ("robots", pulled, snap)})["r1"]
    assert find(commands, f"rm -f {agent_files.REMOTE_CA}")
    result = run_plan(
        {"r1": ("robots", {**https, "pull_remote_ca": str(tmp_path / "tls" / "ca.key")}, fresh_host("debian-13"))}
    )
    assert result.failed == {"r1"} and find(result["r1"], "pull_remote_ca: .*ca.key holds no PEM certificate")


def test_platform_names():
    assert plan.platform("313\n", {}, "amd64") == "cp313-x86_64"
    assert plan.platform("", {"id": "ubuntu", "version_id": "24.04"}, "arm64") == "cp312-aarch64"
    assert plan.platform("", {"id": "fedora", "version_id": "40"}, "amd64") is None
    assert plan.platform("312", {}, "riscv64") is None


def test_install_probe_reads_usable_links_only():
    assert install.read_probe("venv=venvs/abc\ncode=def\n") == {"venv": "abc", "code": "def"}
    assert install.read_probe("venv=\ncode=\n") == {"venv": "", "code": ""}
    assert install.read_probe("") == {"venv": "", "code": ""}
