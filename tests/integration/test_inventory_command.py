"""robotfleet inventory (issue 39, item 6), run as operators run it, beside
Ansible's own ansible-inventory on the same inventories: the same graph;
each host's value with the file, line and group or host that set it;
secrets masked; a note where sibling groups disagree; one line and exit 2
for what is not there.  Nothing is contacted."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tests.fixtures import ROOT
from tests.integration.ansibledirs import ANSIBLE_INVENTORY, INI_HOSTS, VARS, YAML_HOSTS, display, write


def robotfleet(tmp_path: Path, *argv: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "robotfleet", "inventory", *argv],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
        env={"PATH": "/usr/bin:/bin", "HOME": str(tmp_path), **(env or {})},
    )


def ansible_graph(path: Path) -> str:
    assert ANSIBLE_INVENTORY, "ansible-core (the test extra) is not installed"
    return subprocess.run(
        [ANSIBLE_INVENTORY, "-i", str(path), "--graph"],
        capture_output=True,
        text=True,
        check=True,
        env={"PATH": "/usr/bin:/bin", "ANSIBLE_LOCAL_TEMP": str(path.parent / ".ansible"), "HOME": str(path.parent)},
    ).stdout


@pytest.mark.parametrize("layout", ["ini-dir", "yaml-file"])
def test_the_graph_is_ansible_inventorys(tmp_path, layout):
    if layout == "ini-dir":
        path = write(tmp_path / "inventory", {"hosts": INI_HOSTS, **VARS})
    else:
        path = write(tmp_path, {"hosts.yml": YAML_HOSTS}) / "hosts.yml"
    result = robotfleet(tmp_path, "-i", str(path), "--graph")
    assert result.returncode == 0, result.stderr
    assert result.stdout == ansible_graph(path)


def test_a_host_s_values_name_where_they_come_from(tmp_path):
    path = write(tmp_path / "inventory", {"hosts": INI_HOSTS, **VARS})
    result = robotfleet(tmp_path, str(path), "--host", "robot02")
    assert result.returncode == 0, result.stderr
    rows = [line.split() for line in result.stdout.splitlines()]
    shown = display(path)
    assert rows[0] == ["robot02:", "a", "robot,", "in", "robots,", "warehouse_a"]
    # the vars files are YAML: their lines too (issue 54, item 5)
    assert ["ros_domain_id", "99", "host", "robot02", f"({shown}/host_vars/robot02.yml:1)"] in rows
    assert ["over", "3", "group", "warehouse_a", f"({shown}/hosts:16)"] in rows
    assert [
        "ssh_user",
        "root",
        "host",
        "robot02",
        "as",
        "ansible_ssh_user",
        f"({shown}/host_vars/robot02.yml:2)",
    ] in rows
    assert ["over", "ops", "group", "all", "as", "ansible_user", f"({shown}/hosts:27)"] in rows
    assert ["docker_users", '["ops",', '"ci"]', "group", "robots", f"({shown}/group_vars/robots/users:1)"] in rows


def test_secrets_are_masked_and_sibling_groups_that_disagree_are_noted(tmp_path):
    path = write(
        tmp_path / "inventory",
        {
            "hosts": "[robots:children]\nwarehouse_a\nlidar_bots\n\n"
            "[warehouse_a]\nrobot[1:2]\n\n[lidar_bots]\nrobot2\n",
            "group_vars/all.yml": "payload_image: reg.example.com/p:1\nansible_user: ops\n",
            "group_vars/warehouse_a.yml": "ssh_port: 2222\npayload_environment: {DB_URL: 'postgres://u:s3cret@db/x'}\n",
            "group_vars/lidar_bots.yml": "ssh_port: 22\n",
        },
    )
    note = (
        f"{display(path)}/group_vars/warehouse_a.yml: note: robot2: ssh_port is group warehouse_a's, not "
        "lidar_bots's (sibling groups that set it differently; same depth and ansible_group_priority: "
        "warehouse_a sorts after lidar_bots by name, as in Ansible); set it on the host or give one group a "
        "higher ansible_group_priority"
    )
    for argv in (["--host", "robot1"], ["--list"]):
        result = robotfleet(tmp_path, "-i", str(path), *argv)
        assert result.returncode == 0, result.stderr
        assert "s3cret" not in result.stdout and "postgres://u:****@db/x" in result.stdout, result.stdout
        assert result.stderr.splitlines() == [note]
    listed = json.loads(robotfleet(tmp_path, "-i", str(path), "--list").stdout)
    assert listed["_meta"]["hostvars"]["robot2"]["ssh_port"] == 2222
    assert listed["lidar_bots"] == {"hosts": ["robot2"]}


def test_tokens_and_keys_are_masked_as_passwords_are_and_a_key_file_s_path_is_shown(tmp_path):
    """Issue 50, item 4: what a key's last word names a secret is masked in
    --host and --list; a path to a key file and a key's fingerprint are not secrets."""
    path = write(
        tmp_path / "inventory",
        {
            "hosts": "[robots]\nrobot1\n",
            "group_vars/robots.yml": "payload_image: reg.example.com/p:1\nansible_ssh_private_key_file: ~/.ssh/fleet\n"
            "payload_environment: {API_TOKEN: tok-8a2c, AWS_SECRET_ACCESS_KEY: wJalr/XUtn+FEMI, "
            "AWS_ACCESS_KEY_ID: AKIAEXAMPLE, GOOGLE_APPLICATION_CREDENTIALS: /run/secrets/gcp.json}\n",
        },
    )
    for argv in (["--host", "robot1"], ["--list"]):
        result = robotfleet(tmp_path, "-i", str(path), *argv)
        assert result.returncode == 0, result.stderr
        assert "tok-8a2c" not in result.stdout and "XUtn" not in result.stdout, result.stdout
        assert '"API_TOKEN": "****"' in result.stdout and '"AWS_SECRET_ACCESS_KEY": "****"' in result.stdout
        for shown in ("AKIAEXAMPLE", "/run/secrets/gcp.json", "~/.ssh/fleet"):
            assert shown in result.stdout, (shown, result.stdout)


def test_a_pyinfra_inventory_shows_the_fleet_it_reads(tmp_path):
    path = write(tmp_path, {"fleet.yaml": "robots:\n  hosts:\n    robot1: {address: 10.0.0.1, payload_image: r/p:1}\n"})
    result = robotfleet(
        tmp_path, "inventories/robots.py", "--host", "robot1", env={"ROBOT_FLEET": str(path / "fleet.yaml")}
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.splitlines()[2].split()[:2] == ["payload_image", "r/p:1"]


@pytest.mark.parametrize(
    "argv, line",
    [
        (["--host", "robot9"], "inventory: no host 'robot9' in {fleet} (did you mean 'robot1'?)"),
        (["--graph", "robot"], "inventory: --graph robot: no group of that name in {fleet} (did you mean 'robots'?)"),
    ],
)
def test_what_is_not_there_is_one_line(tmp_path, argv, line):
    path = write(tmp_path, {"fleet.yaml": "robots:\n  hosts:\n    robot1: {address: 10.0.0.1, payload_image: r/p:1}\n"})
    result = robotfleet(tmp_path, "-i", str(path / "fleet.yaml"), *argv)
    assert (result.returncode, result.stderr.splitlines()) == (2, [line.format(fleet=display(path / "fleet.yaml"))])


# Issue 54, item 5: paths and lines as the user wrote them.
LATEST = "reg.example.com/ros/payload:latest"


def test_a_fleet_given_by_its_absolute_path_is_named_so(tmp_path):
    """Not relative to where robotfleet runs (../../../tmp/...); through a
    pyinfra inventory's $ROBOT_FLEET too."""
    fleet = (
        write(tmp_path, {"fleet.yaml": f"robots:\n  hosts:\n    robot1: {{payload_image: {LATEST}}}\n"}) / "fleet.yaml"
    )
    refused = f"{fleet}: robot1.payload_image: {LATEST!r} uses the moving tag 'latest'"
    for argv, env in (([str(fleet)], None), (["inventories/robots.py"], {"ROBOT_FLEET": str(fleet)})):
        result = robotfleet(tmp_path, *argv, "--graph", env=env)
        assert result.returncode == 2 and result.stderr.startswith(refused), result.stderr


def test_an_ini_value_s_problem_is_on_the_line_it_is_written(tmp_path):
    """The group's payload_image on line 18, not the host's line (it was hosts:16)."""
    text = "\n".join(["# the fleet", *[""] * 13, "[robots]", "robot1 ansible_host=10.0.0.1", "[robots:vars]"])
    path = write(tmp_path / "inventory", {"hosts": f"{text}\npayload_image={LATEST}\n"})
    result = robotfleet(tmp_path, "-i", str(path), "--graph")
    assert result.stderr.splitlines()[0].startswith(f"{path}/hosts:18: robot1.payload_image: {LATEST!r} uses"), (
        result.stderr
    )


def test_a_yaml_host_s_values_name_their_lines(tmp_path):
    """inventory --host gives the file and line for YAML as for INI, group_vars/ files too."""
    path = write(
        tmp_path,
        {
            "hosts.yaml": "all:\n  vars:\n    ssh_user: ops\nrobots:\n  hosts:\n    robot1:\n"
            "      address: 10.0.0.1\n      payload_image: r/p:1\n",
            "group_vars/robots.yml": "# the robots\ndocker_users: [ops]\n",
        },
    )
    result = robotfleet(tmp_path, "-i", str(path / "hosts.yaml"), "--host", "robot1")
    assert result.returncode == 0, result.stderr
    rows = [line.split() for line in result.stdout.splitlines()]
    assert ["ssh_user", "ops", "group", "all", f"({path}/hosts.yaml:3)"] in rows, rows
    assert ["ssh_hostname", "10.0.0.1", "host", "robot1", "as", "address", f"({path}/hosts.yaml:7)"] in rows, rows
    assert ["docker_users", '["ops"]', "group", "robots", f"({path}/group_vars/robots.yml:2)"] in rows, rows
