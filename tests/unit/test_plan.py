"""The commands deploy.py plans for Ubuntu and Debian hosts (pyinfra @fake
connector with a canned host snapshot), including converged hosts."""

import json
import re

import pytest

from robotfleet.host.fixtures import file_state
from robotfleet.host.snapshot import FileState
from roles.docker import plan as docker_plan
from roles.payload import installed_files
from tests.unit.harness import LAPTOP, ROBOT, converged, everything_sent, find, fresh_host, merged, plan

DOCKER_FPR = "9DC858229FC7DD38854AE2D88D81803C0EBFCD88"
MATRIX = [
    (os_name, arch)
    for os_name in ("ubuntu-20.04", "ubuntu-22.04", "ubuntu-24.04", "debian-12", "debian-13")
    for arch in ("amd64", "arm64")
]


def sources_of(commands):
    """Decode the files the plan writes: path -> content."""
    written = {}
    for command in commands:
        match = re.search(r"dest=(\S+)\n", command)
        if match and "base64 -d" in command:
            written[match.group(1)] = command
    return written


@pytest.mark.parametrize("os_name, arch", MATRIX)
def test_fresh_host_gets_docker_ce_from_dockers_repository(os_name, arch):
    result = plan({"r1": ("robots", ROBOT, fresh_host(os_name, arch))})
    commands = result["r1"]
    dist = os_name.split("-")[0]
    assert result.failed == set()
    key = find(commands, "curl -fsSL")
    assert len(key) == 1
    assert f"https://download.docker.com/linux/{dist}/gpg" in key[0]
    assert f"pin={DOCKER_FPR}" in key[0] and "/etc/apt/keyrings/docker.asc" in key[0]
    assert "/etc/apt/sources.list.d/docker.sources" in sources_of(commands)
    install = find(commands, "install docker-ce docker-ce-cli containerd.io docker-buildx-plugin docker-compose-plugin")
    assert len(install) == 1
    # apt update runs for the new source, before the install.
    assert commands.index(find(commands, r"\napt_locked apt-get -q .* update\n'$")[0]) < commands.index(install[0])
    assert find(commands, "usermod -aG docker ops")
    assert find(commands, "/etc/docker/daemon.json")
    assert find(commands, "systemctl daemon-reload")
    assert find(commands, "payloadctl apply")


@pytest.mark.parametrize("os_name, arch", MATRIX)
def test_docker_sources_file_names_suite_arch_and_key(os_name, arch):
    snap = fresh_host(os_name, arch)
    dist = docker_plan.distribution(snap.os_release)
    text = docker_plan.sources_text(
        docker_plan.repo_uri("https://download.docker.com/linux", dist),
        docker_plan.suite(snap.os_release),
        "stable",
        docker_plan.architecture(arch),
        "/etc/apt/keyrings/docker.asc",
    )
    expected_suite = {
        "ubuntu-20.04": "focal",
        "ubuntu-22.04": "jammy",
        "ubuntu-24.04": "noble",
        "debian-12": "bookworm",
        "debian-13": "trixie",
    }[os_name]
    assert text.splitlines()[1:] == [
        "Types: deb",
        f"URIs: https://download.docker.com/linux/{dist}",
        f"Suites: {expected_suite}",
        "Components: stable",
        f"Architectures: {arch}",
        "Signed-By: /etc/apt/keyrings/docker.asc",
    ]


def test_derivative_uses_ubuntu_codename():
    snap = fresh_host("mint-22")
    assert docker_plan.distribution(snap.os_release) == "ubuntu"
    assert docker_plan.suite(snap.os_release) == "noble"


def test_conflicting_packages_removed_only_where_installed_and_docker_ce_is_not():
    snap = fresh_host("ubuntu-22.04")
    snap.packages.update({"docker.io": "24.0", "runc": "1.1", "containerd": "1.7"})
    commands = plan({"r1": ("robots", ROBOT, snap)})["r1"]
    remove = find(commands, " remove ")
    assert len(remove) == 1 and remove[0].endswith("remove docker.io containerd runc\n'")
    snap.packages["docker-ce"] = "5:28"
    assert not find(plan({"r1": ("robots", ROBOT, snap)})["r1"], " remove ")


def test_legacy_docker_files_are_removed_before_apt_update():
    snap = fresh_host("ubuntu-24.04")
    snap.files["/etc/apt/sources.list.d/docker.list"] = FileState("file", "ab", "644", "root", "root")
    commands = plan({"r1": ("robots", ROBOT, snap)})["r1"]
    removal = find(commands, "rm -f /etc/apt/sources.list.d/docker.list")
    assert removal and commands.index(removal[0]) < commands.index(find(commands, r"update\n'$")[0])


def test_version_pin_and_mirror_urls():
    data = {
        **ROBOT,
        "docker_version": "5:28.5.2-1~ubuntu.24.04~noble",
        "docker_repo_url": "http://mirror.lan/docker",
        "docker_apt_key_url": "http://mirror.lan/key.asc",
        "docker_apt_key_fingerprint": None,
        "docker_apt_key_sha256": "a" * 64,
    }
    commands = plan({"r1": ("robots", data, fresh_host("ubuntu-24.04"))})["r1"]
    install = find(commands, "--allow-downgrades install")[0]
    assert "docker-ce=5:28.5.2-1~ubuntu.24.04~noble" in install
    assert "docker-ce-cli=5:28.5.2-1~ubuntu.24.04~noble" in install and "containerd.io=" not in install
    key = find(commands, "curl -fsSL")[0]
    assert "http://mirror.lan/key.asc" in key and "a" * 64 in key and "gpg" not in key


def test_unsupported_release_fails_that_host_only():
    snap = fresh_host("debian-13")
    snap.os_release.update(version_codename="forky", version_id="14")
    result = plan({"r1": ("robots", ROBOT, snap), "r2": ("robots", ROBOT, fresh_host("debian-13"))})
    assert result.failed == {"r1"}
    assert "debian forky is not supported" in result["r1"][0]
    assert find(result["r2"], "payloadctl apply")


def test_unsupported_architecture_is_refused():
    result = plan({"r1": ("robots", ROBOT, fresh_host("ubuntu-24.04", "armhf"))})
    assert result.failed == {"r1"} and "architecture armhf is not supported" in result["r1"][0]


@pytest.mark.parametrize(
    "os_name, packages", [("debian-13", "docker.io docker-compose"), ("ubuntu-24.04", "docker.io docker-compose-v2")]
)
def test_distro_source_installs_the_distributions_engine(os_name, packages):
    commands = plan({"r1": ("robots", {**ROBOT, "docker_source": "distro"}, fresh_host(os_name))})["r1"]
    assert find(commands, f"install {packages}")
    assert not find(commands, "docker.sources") and not find(commands, "curl")


@pytest.mark.parametrize("os_name", ["debian-12", "ubuntu-20.04"])
def test_distro_source_without_compose_v2_is_refused(os_name):
    result = plan({"r1": ("robots", {**ROBOT, "docker_source": "distro"}, fresh_host(os_name))})
    assert result.failed == {"r1"} and "has no compose v2 package" in result["r1"][0]


def test_missing_docker_user_fails_that_host_and_is_never_created():
    result = plan({"r1": ("robots", {**ROBOT, "docker_users": ["ops", "ghost"]}, fresh_host("debian-13"))})
    assert result.failed == {"r1"}
    assert find(result["r1"], "docker_users: ghost does not exist on this host")
    assert not find(result["r1"], "useradd|usermod")


def test_laptop_gets_x11_and_a_staged_payload_without_autostart():
    commands = plan({"l1": ("laptops", LAPTOP, fresh_host("ubuntu-24.04", users=("alice",)))})["l1"]
    written = sources_of(commands)
    assert "/usr/local/bin/robot-x11-cookie" in written
    assert "/etc/X11/Xsession.d/90robot-x11-cookie" in written
    assert find(commands, "install -d -m 700 -o alice -g alice /var/lib/robot-x11/alice")
    assert "/etc/systemd/system/robot-payload.service" not in written
    assert "xhost" not in everything_sent(commands).replace("`xhost +`", "")  # file contents included
    assert find(commands, "payloadctl apply")


# --- a converged host plans nothing ------------------------------------------


@pytest.mark.parametrize("os_name, arch", MATRIX)
def test_converged_robot_plans_nothing(os_name, arch):
    snap = converged("robots", ROBOT, os_name)
    snap.arch = arch
    snap.files["/etc/apt/sources.list.d/docker.sources"] = converged_sources(snap)
    result = plan({"r1": ("robots", ROBOT, snap)})
    assert result.failed == set()
    assert result["r1"] == []


def converged_sources(snap):
    dist = docker_plan.distribution(snap.os_release)
    return file_state(
        docker_plan.sources_text(
            docker_plan.repo_uri("https://download.docker.com/linux", dist),
            docker_plan.suite(snap.os_release),
            "stable",
            snap.arch,
            "/etc/apt/keyrings/docker.asc",
        )
    )


def test_converged_laptop_plans_nothing():
    result = plan({"l1": ("laptops", LAPTOP, converged("laptops", LAPTOP, "ubuntu-24.04"))})
    assert result["l1"] == []


def test_the_snapshot_memo_earlier_releases_kept_is_removed_once():
    """A robot that still holds the memo of releases before the snapshot
    lost it has it removed (its own directory only), then plans nothing."""
    from robotfleet.provision import EARLIER_MEMO

    snap = converged("laptops", LAPTOP, "ubuntu-24.04")
    snap.files[EARLIER_MEMO] = FileState("dir", None, "700", "root", "root")
    assert plan({"l1": ("laptops", LAPTOP, snap)})["l1"] == [f"rm -rf {EARLIER_MEMO}"]
    snap.files[EARLIER_MEMO] = FileState("link", None, "777", "root", "root")  # not the directory it made
    assert plan({"l1": ("laptops", LAPTOP, snap)})["l1"] == []


@pytest.mark.parametrize(
    "state, containers",
    [
        ("failed", "running\tUp 3 hours (healthy)\n"),  # a first release that failed its health check
        ("switching", "running\tUp 3 hours (healthy)\n"),  # a power cut before its verdict
        ("active", ""),  # the payload is down, the oneshot unit still "active"
        ("active", "exited\tExited (1) 2 minutes ago\n"),
        ("active", "restarting\tRestarting (1) 1 second ago\n"),
        ("active", "running\tUp 2 minutes (unhealthy)\n"),
        ("active", "unit failed"),  # containers up by Docker's restart policy, unit failed
    ],
)
def test_failed_half_done_or_dead_release_is_released_again(state, containers):
    snap = converged("robots", ROBOT, "debian-13")
    if containers == "unit failed":
        snap.units["robot-payload.service"] = ("enabled", "failed")
        containers = "running\tUp 3 hours (healthy)\n"
    record = json.loads(snap.probes["payload_record"])
    snap.probes["payload_record"] = json.dumps({**record, "state": state})
    snap.probes["payload_containers"] = "".join(f"c\t{line}\n" for line in containers.splitlines())
    commands = plan({"r1": ("robots", ROBOT, snap)})["r1"]
    assert len(commands) == 1 and "payloadctl apply" in commands[0]


def test_each_release_has_its_own_run_id_spec_result_and_unit():
    snap = converged("robots", ROBOT, "debian-13")
    data = {**ROBOT, "payload_image": "reg.example.com/ros/payload:1.1"}
    first = plan({"r1": ("robots", data, snap)})["r1"][0]
    second = plan({"r1": ("robots", data, snap)})["r1"][0]
    ids = [re.search(r"--run-id ([0-9T]+-[0-9a-f]{8})", c).group(1) for c in (first, second)]
    assert ids[0] != ids[1]
    for run_id, command in zip(ids, (first, second)):
        assert f"/var/lib/robot-payload/runs/{run_id}/spec.json" in command
        assert f"--unit=robot-payload-update-{run_id}" in command
        assert f"result --dir /var/lib/robot-payload --name robot-payload --run-id {run_id}" in command
        assert "|| true" in command and "staging/spec.json" not in command


def test_changed_image_tag_only_releases_the_payload():
    snap = converged("robots", ROBOT, "debian-13")
    commands = plan({"r1": ("robots", {**ROBOT, "payload_image": "reg.example.com/ros/payload:1.1"}, snap)})["r1"]
    assert len(commands) == 1 and "payloadctl apply" in commands[0] and "--restart" not in commands[0]


def test_drifted_file_mode_is_fixed_without_rewriting():
    snap = converged("robots", ROBOT, "debian-13")
    state = snap.files["/etc/docker/daemon.json"]
    snap.files["/etc/docker/daemon.json"] = FileState("file", state.sha256, "666", "root", "root")
    commands = plan({"r1": ("robots", ROBOT, snap)})["r1"]
    # Owner and mode only: Docker is not restarted.
    assert commands == ["sh -c 'chown root:root /etc/docker/daemon.json && chmod 600 /etc/docker/daemon.json'"]


def test_daemon_json_and_its_previous_copy_written_0644_by_an_older_version_become_0600():
    """daemon.json may hold proxy credentials (issue 27, item 7): a host an
    older version left with 0644 files gets both chmod-ed, Docker untouched."""
    snap = converged("robots", ROBOT, "debian-13")
    state = snap.files["/etc/docker/daemon.json"]
    assert state.mode == "600"
    snap.files["/etc/docker/daemon.json"] = FileState("file", state.sha256, "644", "root", "root")
    snap.files["/etc/docker/daemon.json.previous"] = FileState("file", "ab" * 32, "644", "root", "root")
    commands = plan({"r1": ("robots", ROBOT, snap)})["r1"]
    assert commands == [
        "sh -c 'chown root:root /etc/docker/daemon.json && chmod 600 /etc/docker/daemon.json && "
        "chown root:root /etc/docker/daemon.json.previous && chmod 600 "
        "/etc/docker/daemon.json.previous'"
    ]
    snap.files["/etc/docker/daemon.json"] = state
    snap.files["/etc/docker/daemon.json.previous"] = FileState("file", "ab" * 32, "600", "root", "root")
    assert plan({"r1": ("robots", ROBOT, snap)})["r1"] == []


def test_changed_daemon_json_is_validated_kept_and_restored_if_docker_does_not_start():
    snap = converged("robots", ROBOT, "debian-13")
    data = {**ROBOT, "docker_registry_mirrors": ["https://mirror.lan"], "docker_restart_timeout": 20}
    commands = plan({"r1": ("robots", data, snap)})["r1"]
    assert len(commands) == 2 and "payloadctl apply" in commands[1]  # the payload checked after the restart
    script = commands[0]
    # Validated first, the old file kept, then the restart with a bound.
    assert script.index("dockerd --validate --config-file") < script.index('(umask 077 && cat "$dest" > "$prev.tmp")')
    assert "cp -Pp" not in script and 'chmod 600 "$tmp"' in script
    assert script.index('mv -fT "$tmp" "$dest"') < script.index("systemctl restart docker.service")
    assert "prev=/etc/docker/daemon.json.previous" in script and "timeout=20" in script
    assert 'if [ -f "$prev" ]; then mv -fT "$prev" "$dest"; else rm -f "$dest"; fi' in script
    assert "the previous daemon.json is restored" in script
    # Where dockerd has no --validate the operator is told so.
    assert "warning: docker: this dockerd has no --validate (Docker < 23)" in script


def test_daemon_json_written_but_not_applied_restarts_docker_on_the_next_run():
    snap = converged("robots", ROBOT, "debian-13")
    snap.files["/etc/docker/daemon.json.pending"] = FileState("file", "e3" * 32, "644", "root", "root")
    commands = plan({"r1": ("robots", ROBOT, snap)})["r1"]
    assert len(commands) == 2 and "payloadctl apply" in commands[1]  # the payload checked after the restart
    assert "systemctl restart docker.service" in commands[0] and 'rm -f "$pending"' in commands[0]
    assert "base64 -d" not in commands[0]


def test_interrupted_dpkg_is_finished_before_any_install():
    snap = fresh_host("ubuntu-24.04")
    snap.probes["dpkg_audit"] = "dpkg journal not empty\n"
    commands = plan({"r1": ("robots", ROBOT, snap)})["r1"]
    repair = find(commands, "dpkg --force-confdef --force-confold --configure -a")
    installs = find(commands, " install ")
    assert len(repair) == 1 and commands.index(repair[0]) < commands.index(installs[0])
    snap.probes["dpkg_audit"] = ""
    assert not find(plan({"r1": ("robots", ROBOT, snap)})["r1"], "--configure -a")


def test_apt_waits_for_its_locks_with_the_configured_bound():
    commands = plan({"r1": ("robots", {**ROBOT, "apt_lock_timeout": 7}, fresh_host("debian-13"))})["r1"]
    apt = find(commands, "apt-get")
    assert apt and all("apt_lock_timeout=7\n" in c and "apt_locked " in c for c in apt)
    assert not find(commands, "Lock::Timeout=600")


def test_changed_unit_reloads_systemd_and_restarts_the_payload():
    snap = converged("robots", ROBOT, "debian-13")
    snap.files[installed_files.unit_path(merged("robots", ROBOT))] = file_state("old unit")
    commands = plan({"r1": ("robots", ROBOT, snap)})["r1"]
    assert find(commands, "systemctl daemon-reload")
    assert "--restart" in find(commands, "payloadctl apply")[0]


def test_changed_sensor_rules_reload_udev_for_their_subsystems_only():
    snap = converged("robots", ROBOT, "debian-13")
    snap.files["/etc/udev/rules.d/70-robot-sensors.rules"] = file_state("# old\n")
    commands = plan({"r1": ("robots", ROBOT, snap)})["r1"]
    reload = find(commands, "udevadm control --reload-rules")
    assert len(reload) == 1
    assert "--subsystem-match=tty" in reload[0] and "--subsystem-match=video4linux" in reload[0]
    assert "--subsystem-match=usb-serial" in reload[0]


def test_registry_credentials_come_from_the_environment_and_go_over_stdin(monkeypatch):
    monkeypatch.setenv("PAYLOAD_REGISTRY_USERNAME", "robot")
    monkeypatch.setenv("PAYLOAD_REGISTRY_PASSWORD", "s3cret-token")
    commands = plan({"r1": ("robots", ROBOT, converged("robots", ROBOT, "debian-13"))})["r1"]
    login = find(commands, "docker login")
    assert len(login) == 1
    assert "docker login reg.example.com --username robot --password-stdin >/dev/null" in login[0]
    assert login[0].stdin.rstrip("\n").endswith("s3cret-token")
    assert [c for c in commands if "s3cret-token" in f"{c}\n{c.stdin}"] == login
    assert "s3cret-token" not in str(login[0])


def test_snapshot_encoding_roundtrip():
    snap = converged("robots", ROBOT, "debian-13")
    from robotfleet.host.snapshot import parse
    from tests.unit.harness import query_of, snapshot_lines

    again = parse(snapshot_lines(snap, query_of(snap)), query_of(snap))
    assert again.files == snap.files and again.probes == snap.probes and again.packages == snap.packages
    assert again.users == snap.users and again.units == snap.units and again.os_release == snap.os_release


def test_bad_override_data_fails_that_host_before_anything_runs():
    result = plan(
        {
            "r1": ("robots", {**ROBOT, "docker_apt_key_fingerprint": 0, "ssh_port": "x"}, fresh_host("debian-13")),
            "r2": ("robots", ROBOT, fresh_host("debian-13")),
        }
    )
    assert result.failed == {"r1"}
    assert len(result["r1"]) == 1 and "settings: " in result["r1"][0]
    assert "docker_apt_key_fingerprint: expected a string, got 0" in result["r1"][0]
    assert "ssh_port: expected a whole number" in result["r1"][0]
    assert find(result["r2"], "payloadctl apply")


def test_a_deploy_that_finds_the_boot_recovery_holding_the_lock_says_it_waits(caplog):
    snap = converged("robots", ROBOT, "debian-13")
    snap.probes["payload_lock"] = json.dumps(
        {"action": "start", "by": "boot", "since": "2026-11-23T10:00:00Z", "pid": 7}
    )
    data = {**ROBOT, "payload_image": "reg.example.com/ros/payload:1.1"}
    commands = plan({"r1": ("robots", data, snap)})["r1"]
    assert (
        "[@fake/r1] @fake/r1 is recovering from an interrupted release since 2026-11-23T10:00:00Z; waiting"
    ) in caplog.text
    assert len(commands) == 1 and "payloadctl apply" in commands[0]  # the release waits on the robot, bounded


def test_the_payload_is_checked_after_a_docker_restart_this_run_caused():
    """A daemon.json Docker accepts (a new data-root) can lose the running
    payload: the release is checked, and made again, in that same run
    (issue 17, item 10)."""
    snap = converged("robots", ROBOT, "debian-13")
    data = {**ROBOT, "docker_daemon_options": {"live-restore": True, "data-root": "/srv/docker"}}
    commands = plan({"r1": ("robots", data, snap)})["r1"]
    assert len(commands) == 2
    assert "daemon.json" in commands[0] and "systemctl restart docker.service" in commands[0]
    assert "payloadctl apply" in commands[1] and "--restart" not in commands[1]
    assert plan({"r1": ("robots", ROBOT, snap)})["r1"] == []  # no restart, no check
