"""The time role: its settings' checks, the chrony.conf and drop-in it
renders, and the commands it plans (pyinfra @fake with a canned snapshot)."""

from __future__ import annotations

import base64

import pytest
import yaml

import roles.time as time_role
import roles.time.plan as plan
from robotfleet.host.fixtures import file_state
from tests.fixtures import ROOT
from tests.fixtures import good_robot as robot
from tests.unit.harness import LAPTOP, ROBOT, converged, find, fleet_problems, fresh_host, merged, written_files
from tests.unit.harness import plan as run_plan

SERVER = {**ROBOT, "time_serve": True, "time_allow": ["10.20.0.0/24"], "time_servers": ["ntp1.lan", "10.20.0.1"]}
CLIENT = {**ROBOT, "time_servers": ["10.20.0.11"]}
RELEASES = ["ubuntu-22.04", "ubuntu-24.04", "debian-12", "debian-13"]
# /proc/1/status CapBnd: a stock host's, and a lab container's (no CAP_SYS_TIME, bit 25).
FULL_BOUNDING_SET = "000001ffffffffff"
CONTAINER_BOUNDING_SET = "00000000a82435fb"
RESTART = r"^systemctl restart chrony\.service$"
RELOAD = r"^systemctl daemon-reload$"


@pytest.mark.parametrize(
    "doc, expected",
    [
        (
            robot(time_serve=True),
            "robots.yaml: robot3.time_allow: required when time_serve is true: the networks that may ask this host "
            "for time (e.g. 10.20.0.0/24); nothing is open by default",
        ),
        (
            robot(time_servers=["ntp server.lan"]),
            "robots.yaml: robot3.time_servers[0]: expected a host name or an IP address, got 'ntp server.lan'",
        ),
        (
            robot(time_servers=["fe80::1%eth0\nallow all"]),  # the engine's address check refuses the newline
            "robots.yaml: robot3.time_servers[0]: expected a host name or an IP address, got 'fe80::1%eth0\\nallow "
            "all'",
        ),
        (
            robot(time_servers=["fe80::1%eth0"]),  # chrony's server line takes no zone
            "robots.yaml: robot3.time_servers[0]: expected a host name or an IP address without a zone (%interface), "
            "got 'fe80::1%eth0'",
        ),
        (robot(time_servers="ntp.lan"), "robots.yaml: robot3.time_servers: expected a list, got 'ntp.lan'"),
        (robot(time_servers=["ntp.lan", "ntp.lan"]), "robots.yaml: robot3.time_servers[1]: duplicate entry 'ntp.lan'"),
        (
            robot(time_servers=["10.0.0.3"]),
            "robots.yaml: robot3.time_servers[0]: 10.0.0.3 is this host itself; a host does not follow its own clock "
            "(give it time_servers: [] or other servers)",
        ),
        (
            robot(time_serve=True, time_allow=["10.20.0.0/33"]),
            "robots.yaml: robot3.time_allow[0]: expected a network like 10.20.0.0/24 or an address, got '10.20.0.0/33'",
        ),
        (
            robot(time_serve=True, time_allow=["lan"]),
            "robots.yaml: robot3.time_allow[0]: expected a network like 10.20.0.0/24 or an address, got 'lan'",
        ),
        (
            robot(time_serve=True, time_allow=["10.20.0.0/24 allow all"]),
            "robots.yaml: robot3.time_allow[0]: expected a network like 10.20.0.0/24 or an address, "
            "got '10.20.0.0/24 allow all'",
        ),
        (robot(time_serve="yes"), "robots.yaml: robot3.time_serve: expected true or false, got 'yes'"),
        (robot(time_set_clock=0), "robots.yaml: robot3.time_set_clock: expected true or false, got 0"),
        (robot(time_local_stratum=16), "robots.yaml: robot3.time_local_stratum: expected at most 15, got 16"),
    ],
)
def test_bad_time_settings_get_one_clear_line(doc, expected):
    assert fleet_problems(doc) == [expected]


@pytest.mark.parametrize(
    "extra",
    [
        {"time_servers": ["ntp.lan", "10.20.0.1", "fd00::1"]},
        {"time_serve": True, "time_allow": ["10.20.0.0/24", "10.30.0.7", "fd00::/64"]},
        {"time_allow": ["10.20.0.0/24"]},  # set for the whole fleet in all.vars; used where time_serve is true
    ],
)
def test_good_time_settings_are_accepted(extra):
    assert fleet_problems(robot(**extra)) == []


def test_a_refused_time_allow_is_not_reported_twice():
    assert len(fleet_problems(robot(time_serve=True, time_allow="10.20.0.0/24"))) == 1


def test_serving_chrony_conf():
    data = merged("robots", {**SERVER, "time_allow": ["10.20.0.0/24", "10.30.0.7/16", "fd00::1"]})
    assert plan.chrony_conf(data) == (
        "# Managed by the robot fleet provisioner (roles/time) from the fleet file's\n"
        "# time_* settings; local edits are overwritten.\n"
        "\n"
        "server ntp1.lan iburst\n"
        "server 10.20.0.1 iburst\n"
        "\n"
        "driftfile /var/lib/chrony/chrony.drift\n"
        "# Step the clock when it is off by more than a second in the first three\n"
        "# updates (a robot without a real-time clock boots far off); slew after.\n"
        "makestep 1 3\n"
        "rtcsync\n"
        "\n"
        "# time_serve: these may ask this host for time; it answers from its own\n"
        "# clock at this stratum while none of its servers does.\n"
        "allow 10.20.0.0/24\n"
        "allow 10.30.0.0/16\n"
        "allow fd00::1/128\n"
        "local stratum 10\n"
    )


def test_a_client_allows_nobody_and_a_server_without_upstream_keeps_its_clock():
    client = plan.chrony_conf(merged("robots", CLIENT))
    assert "server 10.20.0.11 iburst\n" in client
    assert "allow" not in client and "local stratum" not in client
    alone = plan.chrony_conf(merged("robots", {**SERVER, "time_servers": [], "time_local_stratum": 8}))
    assert "server " not in alone and "pool " not in alone
    assert "# No time_servers: this host keeps its own clock.\n" in alone and alone.endswith("local stratum 8\n")


def test_the_drop_in_runs_chronyd_with_x_and_lifts_the_capability_condition():
    text = plan.drop_in()
    lines = [line for line in text.splitlines() if line and not line.startswith("#")]
    assert lines == [
        "[Unit]",
        "ConditionCapability=",
        "[Service]",
        "Type=simple",
        "PIDFile=",
        "ExecStart=",
        "ExecStart=!/usr/sbin/chronyd -n -x $DAEMON_OPTS",
    ]


@pytest.mark.parametrize("os_name", RELEASES)
def test_fresh_host_gets_chrony_configured_checked_and_started(os_name):
    result = run_plan({"r1": ("robots", SERVER, fresh_host(os_name))})
    commands = result["r1"]
    assert result.failed == set()
    install = find(commands, r"--allow-downgrades install chrony(;| \|\|)")
    assert len(install) == 1
    conf = find(commands, r"dest=/etc/chrony/chrony.conf\n")
    assert len(conf) == 1 and 'chronyd -p -f "$tmp" >/dev/null' in conf[0]
    assert written_files(commands)[plan.CONF] == plan.chrony_conf(merged("robots", SERVER))
    # No drop-in, so no daemon-reload of its own (the payload role reloads for its unit).
    without = run_plan({"r1": ("robots", ROBOT, fresh_host(os_name))})["r1"]
    assert plan.DROP_IN not in written_files(commands) and len(find(commands, RELOAD)) == len(find(without, RELOAD))
    # Restarted once, after the file is in place; then enabled (start is a no-op by then).
    assert len(find(commands, RESTART)) == 1
    order = [
        commands.index(c)
        for c in (install[0], conf[0], find(commands, RESTART)[0], find(commands, "systemctl enable chrony.service")[0])
    ]
    assert order == sorted(order)
    # After Docker's installs (dpkg repaired there), before the payload.
    assert commands.index(find(commands, "docker-compose-plugin")[0]) < commands.index(install[0])
    assert commands.index(install[0]) < commands.index(find(commands, "payloadctl apply")[0])


def test_the_write_command_checks_the_file_with_chronyd_before_replacing_it():
    conf = find(run_plan({"r1": ("robots", CLIENT, fresh_host("debian-13"))})["r1"], r"dest=/etc/chrony/chrony.conf\n")[
        0
    ]
    check = conf.index('chronyd -p -f "$tmp"')
    assert conf.index("chronyd -v") < check < conf.index('mv -fT "$tmp" "$dest"')
    assert '"${major:-0}" -ge 4' in conf  # chrony 3.5 would fork a daemon on -p


@pytest.mark.parametrize("os_name", RELEASES)
@pytest.mark.parametrize(
    "data", [SERVER, CLIENT, {**CLIENT, "time_set_clock": False}], ids=["server", "client", "no-clock"]
)
def test_converged_host_plans_nothing(os_name, data):
    snap = converged("robots", data, os_name)
    snap.probes[time_role.CAPABILITIES_PROBE] = FULL_BOUNDING_SET
    result = run_plan({"r1": ("robots", data, snap)})
    assert result.failed == set()
    assert result["r1"] == []


def test_a_changed_server_rewrites_the_file_and_restarts_chrony_once():
    snap = converged("robots", CLIENT, "debian-13")
    changed = {**CLIENT, "time_servers": ["10.20.0.12"]}
    commands = run_plan({"r1": ("robots", changed, snap)})["r1"]
    assert len(commands) == 2
    assert "server 10.20.0.12 iburst\n" in written_files(commands)[plan.CONF]
    assert len(find(commands, RESTART)) == 1 and commands.index(find(commands, RESTART)[0]) == 1


def test_time_set_clock_false_adds_the_drop_in_reloads_systemd_and_restarts():
    snap = converged("robots", CLIENT, "debian-13")
    commands = run_plan({"r1": ("robots", {**CLIENT, "time_set_clock": False}, snap)})["r1"]
    assert written_files(commands) == {plan.DROP_IN: plan.drop_in()}
    assert len(find(commands, RELOAD)) == 1 and len(find(commands, RESTART)) == 1
    assert commands.index(find(commands, RELOAD)[0]) < commands.index(find(commands, RESTART)[0])


def test_time_set_clock_true_again_removes_the_drop_in():
    snap = converged("robots", {**CLIENT, "time_set_clock": False}, "debian-13")
    snap.probes[time_role.CAPABILITIES_PROBE] = FULL_BOUNDING_SET
    commands = run_plan({"r1": ("robots", CLIENT, snap)})["r1"]
    assert len(commands) == 3
    assert find(commands, f"rm -f {plan.DROP_IN}") and find(commands, RELOAD) and find(commands, RESTART)


def test_a_host_that_cannot_set_its_clock_is_refused_unless_time_set_clock_is_false():
    snap = fresh_host("debian-13")
    snap.probes[time_role.CAPABILITIES_PROBE] = CONTAINER_BOUNDING_SET + "\n"
    result = run_plan({"r1": ("robots", CLIENT, snap), "r2": ("robots", {**CLIENT, "time_set_clock": False}, snap)})
    assert result.failed == {"r1"}
    assert find(
        result["r1"],
        "time_set_clock: this host cannot set its clock \\(no CAP_SYS_TIME: a container\\?\\); "
        "set time_set_clock: false",
    )
    assert not find(result["r1"], "chrony")
    assert plan.DROP_IN in written_files(result["r2"])


def test_capability_probe():
    assert plan.can_set_clock(FULL_BOUNDING_SET + "\n") is True
    assert plan.can_set_clock(CONTAINER_BOUNDING_SET) is False
    assert plan.can_set_clock("") is None  # unread: chrony's own unit decides


def test_a_stopped_chrony_is_started_without_a_restart():
    snap = converged("robots", CLIENT, "ubuntu-24.04")
    snap.units[plan.UNIT] = ("enabled", "failed")
    commands = run_plan({"r1": ("robots", CLIENT, snap)})["r1"]
    assert commands == ["sh -c 'systemctl start chrony.service'"]


def test_other_time_daemons_are_named_in_the_install_step():
    installed = {"systemd-timesyncd": "255", "docker-ce": "5:28"}
    assert plan.replaced(installed) == ["systemd-timesyncd"]
    assert plan.replaced({"ntpsec": "1", "openntpd": "1"}) == ["ntpsec", "openntpd"]


def test_the_role_is_opt_in():
    """Without time settings a host reads and plans nothing of chrony."""
    result = run_plan({"r1": ("robots", ROBOT, fresh_host("debian-13"))})
    assert "chrony" not in result.queries["r1"]["packages"]
    assert time_role.CAPABILITIES_PROBE not in result.queries["r1"]["probes"]
    assert not find(result["r1"], "chrony")
    assert time_role.runs_on(merged("robots", {"time_serve": True, "time_allow": ["10.0.0.0/8"]}))
    assert not time_role.runs_on(merged("robots", {"time_allow": ["10.0.0.0/8"]}))


def test_every_host_read_is_declared():
    result = run_plan({"r1": ("robots", SERVER, fresh_host("debian-13"))})
    query = result.queries["r1"]
    assert {"chrony", "systemd-timesyncd"} <= set(query["packages"])
    assert {plan.CONF, plan.DROP_IN} <= set(query["files"]) and plan.UNIT in query["units"]
    assert query["probes"][time_role.CAPABILITIES_PROBE] == "sed -n 's/^CapBnd:[[:space:]]*//p' /proc/1/status"


def test_the_readme_example_is_a_valid_fleet():
    text = (ROOT / "roles" / "time" / "README.md").read_text()
    example = yaml.safe_load(text.split("```yaml\n", 1)[1].split("```", 1)[0])
    example["all"]["vars"]["payload_image"] = "reg.example.com/ros/payload:1.0"
    assert fleet_problems(example) == []


def test_a_drifted_conf_is_rewritten():
    snap = converged("robots", SERVER, "debian-13")
    snap.files[plan.CONF] = file_state("pool 2.debian.pool.ntp.org iburst\n")
    commands = run_plan({"r1": ("robots", SERVER, snap)})["r1"]
    assert base64.b64decode(find(commands, "dest=/etc/chrony/chrony.conf")[0].stdin).decode() == plan.chrony_conf(
        merged("robots", SERVER)
    )
    assert len(find(commands, RESTART)) == 1


def test_a_fleet_where_some_hosts_keep_time_plans_every_host():
    """One server, clients with and without the clock, a laptop, and a robot
    without the role: the hosts run different roles, and pyinfra's CLI must
    agree on one order of operations for them all."""
    no_clock = {**CLIENT, "time_set_clock": False}
    result = run_plan(
        {
            "robot1": ("robots", {**SERVER, "time_set_clock": False}, fresh_host("debian-13")),
            "robot2": ("robots", no_clock, fresh_host("debian-13")),
            "robot3": ("robots", ROBOT, fresh_host("debian-13")),
            "robot4": ("robots", CLIENT, fresh_host("ubuntu-24.04")),
            "laptop1": (
                "laptops",
                {**LAPTOP, "time_servers": ["10.20.0.11"]},
                fresh_host("ubuntu-22.04", users=("alice",)),
            ),
        }
    )
    assert result.failed == set()
    for host in ("robot1", "robot2", "robot4", "laptop1"):
        assert len(find(result[host], RESTART)) == 1, host
    assert not find(result["robot3"], "chrony")
    assert plan.DROP_IN in written_files(result["robot2"]) and plan.DROP_IN not in written_files(result["robot4"])
