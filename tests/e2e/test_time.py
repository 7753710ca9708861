"""The time role for real: robot1 serves time, robot2, robot3 and laptop1
follow it with chrony, provisioned over SSH from a copy of the lab fleet
that adds only the time settings.

What the lab cannot prove: its hosts are containers without CAP_SYS_TIME
sharing this machine's kernel clock, so chrony cannot set a clock there.
They run time_set_clock: false (chronyd -x), and the module proves that
the hosts track the server (source selected, reference ID, offsets), that
robot1 answers them from its own clock, and that the role converges; not
that a clock is stepped or slewed (makestep, rtcsync), nor a real upstream
server (no internet), nor chrony 3.5 (Ubuntu 20.04: no config check), nor
systemd-timesyncd being replaced (the lab image has none; the unit tests
plan it).

Module cost, on top of the shared lab and first run: three provisionings
of the four hosts (with the time settings 7-23 s, the counted rerun 2-3 s,
robot1's stratum changed 2-3 s, measured on 2 shared CPUs with a warm apt
cache), waiting for chrony to select its source (seconds: iburst) and the
purge; 35-60 s in all (the whole session with a fresh lab: 96-100 s).  At
the end chrony is purged from the hosts, as the shared first run left them
(the _chrony user stays).
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import time

import pytest

import roles.time.plan as plan
from tests.bench.roundtrips import COUNTING
from tests.e2e.conftest import ROOT, phase, wait_for
from tests.fixtures import pyinfra_argv

pytestmark = pytest.mark.e2e

CLIENTS = ("robot2", "robot3", "laptop1")
LOCAL_REFERENCE = "7F7F0101"  # chrony's reference ID while serving from its own clock ("local")


def network(lab) -> tuple[str, str]:
    """(the lab network's subnet, robot1's address on it)."""
    from tests.lab.engine import client

    name = f"{lab.prefix}-net"
    subnet = client().networks.get(name).attrs["IPAM"]["Config"][0]["Subnet"]
    address = client().containers.get(f"{lab.prefix}-robot1").attrs["NetworkSettings"]["Networks"][name]["IPAddress"]
    return subnet, address


def time_fleet(lab, tmp_path, subnet: str, stratum: int = 10):
    """inventories/lab.yaml with robot1 serving the lab network and the other
    hosts following it by its container name (Docker's DNS on the network)."""
    return lab.fleet_with(
        tmp_path,
        **{
            "    payload_device_wait: 10\n": (
                f"    payload_device_wait: 10\n    time_servers: [{lab.prefix}-robot1]\n    time_set_clock: false\n"
            ),
            "    robot1:\n": (
                "    robot1:\n"
                "      time_servers: []\n"
                "      time_serve: true\n"
                f'      time_allow: ["{subnet}"]\n'
                f"      time_local_stratum: {stratum}\n"
            ),
        },
    )


def tracked_source(lab, host: str) -> str | None:
    """The address of the source chrony selected (^*), if any."""
    for line in lab.ok(host, "chronyc -n sources").splitlines():
        if line.startswith("^*"):
            return line.split()[1]
    return None


def tracking(lab, host: str) -> dict[str, str]:
    return dict(
        re.split(r"\s*:\s*", line, maxsplit=1)
        for line in lab.ok(host, "chronyc -n tracking").splitlines()
        if ":" in line
    )


@pytest.fixture(scope="module")
def served(lab, first_run, tmp_path_factory):
    """The lab provisioned with the time settings; chrony purged afterwards."""
    for host in lab.hosts:  # the role is opt-in: the standard fleet's run left chrony out
        assert lab.sh(host, "dpkg-query -W -f '${Status}' chrony 2>/dev/null | grep -q 'ok installed'")[0] != 0
    subnet, address = network(lab)
    fleet = time_fleet(lab, tmp_path_factory.mktemp("time"), subnet)
    run = lab.provision(fleet=fleet, label="(time: robot1 serves)")
    assert run.returncode == 0, run.output[-6000:]
    yield {"fleet": fleet, "run": run, "subnet": subnet, "address": address}
    for host in lab.hosts:
        lab.ok(
            host,
            "systemctl disable --now chrony.service && "
            "DEBIAN_FRONTEND=noninteractive apt-get purge -y -q chrony && "
            f"rm -rf {os.path.dirname(plan.DROP_IN)} && systemctl daemon-reload",
        )


TIME_STEPS = [
    f"Time (chrony) | {name}"
    for name in (
        "Install chrony",
        "Write /etc/chrony/chrony.conf",
        "chrony never sets the clock (-x, drop-in)",
        "Reload systemd units",
        "Restart chrony with the new configuration",
        "chrony enabled and running",
    )
]


def test_every_host_got_chrony_in_the_time_role_s_steps(lab, served):
    """(Other steps may change too: the fleet copy also brings back whatever
    an earlier module left differing from inventories/lab.yaml.)"""
    run = served["run"]
    assert run.failed_hosts == set()
    for host in lab.hosts:
        assert [name for name in run.changes(host) if name.startswith("Time (chrony) | ")] == TIME_STEPS, host


def test_every_client_tracks_robot1(lab, served):
    address = served["address"]
    for host in CLIENTS:
        wait_for(lambda: tracked_source(lab, host) == address, 60, f"{host} to select robot1 ({address})")
        state = tracking(lab, host)
        assert state["Reference ID"].split()[1] == f"({address})", state
        assert state["Stratum"] == "11" and state["Leap status"] == "Normal", state
        offset = float(state["System time"].split()[0])
        assert offset < 0.01, state  # one kernel clock: only measurement noise


def test_robot1_serves_the_lab_network_from_its_own_clock(lab, served):
    state = tracking(lab, "robot1")
    assert state["Reference ID"].startswith(LOCAL_REFERENCE) and state["Stratum"] == "10", state
    conf = lab.ok("robot1", f"cat {plan.CONF}")
    assert f"allow {served['subnet']}\n" in conf and "local stratum 10\n" in conf and "\nserver " not in conf
    wait_for(
        lambda: (
            int(re.search(r"NTP packets received\s*:\s*(\d+)", lab.ok("robot1", "chronyc serverstats"))[1])
            >= len(CLIENTS)
        ),
        30,
        "robot1 to answer its clients",
    )


def test_chronyd_runs_without_setting_the_clock(lab, served):
    for host in lab.hosts:
        assert lab.ok(host, "systemctl is-active chrony.service").strip() == "active"
        assert lab.ok(host, "systemctl is-enabled chrony.service").strip() == "enabled"
        assert lab.ok(host, f"cat {plan.DROP_IN}") == plan.drop_in()
        assert "Disabled control of system clock" in lab.ok(host, "journalctl -b -u chrony.service --no-pager")
    for host in CLIENTS:
        conf = lab.ok(host, f"cat {plan.CONF}")
        assert f"server {lab.prefix}-robot1 iburst\n" in conf and "allow" not in conf


def test_the_config_check_is_debian_13_chronyds_own(lab, served):
    """The check the role runs before replacing chrony.conf, on a file it
    would never render: chronyd refuses it, naming the line."""
    check = plan.VALIDATE.replace("{}", '"$tmp"')
    lab.ok("robot2", f"tmp={plan.CONF}; {check}")
    code, output = lab.sh(
        "robot2", f"printf 'server x iburst\\nlocal stratum 99\\n' > /root/broken.conf; tmp=/root/broken.conf; {check}"
    )
    assert code != 0 and "Could not parse local directive at line 2" in output, output


def test_a_rerun_changes_nothing_in_one_ssh_command_per_host(lab, served):
    report = ROOT / ".lab" / lab.prefix / "time-roundtrips.json"
    env = dict(os.environ, ROBOT_LAB_PREFIX=lab.prefix, ROBOT_LAB_FLEET=str(served["fleet"]), PYINFRA_PROGRESS="off")
    started = time.monotonic()
    proc = subprocess.run(
        pyinfra_argv(str(report), "-y", "--json", "inventories/lab.py", "deploy.py", setup=COUNTING),
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    phase(f"pyinfra deploy.py (time: rerun, counted) (exit {proc.returncode})", started)
    assert proc.returncode == 0, (proc.stderr + proc.stdout)[-4000:]
    results = json.loads(proc.stdout)["results"]
    changed = {host for op in results["operations"] for host in op["success"]}
    assert changed == set()
    counts = json.loads(report.read_text())
    assert {host: counts[host]["commands"] for host in lab.hosts} == {host: 1 for host in lab.hosts}


def test_a_changed_stratum_restarts_robot1_alone_and_the_clients_follow(lab, served, tmp_path):
    """Last: it leaves robot1 at stratum 8 (the module's teardown purges chrony)."""
    before = {host: lab.ok(host, "systemctl show -p MainPID --value chrony.service") for host in lab.hosts}
    changed = lab.provision(fleet=time_fleet(lab, tmp_path, served["subnet"], stratum=8), label="(time: stratum 8)")
    assert changed.returncode == 0, changed.output[-4000:]
    assert changed.changed_hosts == {"robot1"}
    assert changed.changes("robot1") == [
        "Time (chrony) | Write /etc/chrony/chrony.conf",
        "Time (chrony) | Restart chrony with the new configuration",
    ]
    assert lab.ok("robot1", "systemctl show -p MainPID --value chrony.service") != before["robot1"]
    for host in CLIENTS:
        assert lab.ok(host, "systemctl show -p MainPID --value chrony.service") == before[host]
        lab.ok(host, "chronyc burst 2/4")  # ask now rather than at the next 64 s poll
        wait_for(lambda: tracking(lab, host)["Stratum"] == "9", 60, f"{host} to see robot1 at stratum 8")
