"""An Ansible inventory as operators keep it (issue 28, items 2 to 5): an
INI or YAML inventory, alone or in a directory, with group_vars/ and
host_vars/ beside it; host ranges; Ansible's older ansible_ssh_* names.
Each directory is read twice: by robotfleet, and by Ansible itself
(ansible-inventory from ansible-core, the test extra), and each host's
settings must be the ones Ansible gives it."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from robotfleet.fleet import hostpattern, ini
from tests.fixtures import ROOT
from tests.integration.ansibledirs import ANSIBLE_INVENTORY, IMAGE, INI_HOSTS, VARS, YAML_HOSTS, display, write
from tests.unit.harness import FleetError, load

# Ansible's names as ours (robotfleet/fleet/connection.py ALIASES)
OURS = {
    "ansible_host": "ssh_hostname",
    "ansible_user": "ssh_user",
    "ansible_port": "ssh_port",
    "ansible_private_key_file": "ssh_key",
}
OLDER = {
    "ansible_ssh_host": "ssh_hostname",
    "ansible_ssh_user": "ssh_user",
    "ansible_ssh_port": "ssh_port",
    "ansible_ssh_private_key_file": "ssh_key",
}


def ours(path: Path) -> dict[str, dict]:
    fleet = load(path)
    return {name: data for hosts in fleet.groups.values() for name, data in hosts}


def ansibles(path: Path) -> dict[str, dict]:
    """Each host's settings as Ansible has them, under our names."""
    assert ANSIBLE_INVENTORY, "ansible-core (the test extra) is not installed"
    out = subprocess.run(
        [ANSIBLE_INVENTORY, "-i", str(path), "--list"],
        capture_output=True,
        text=True,
        check=True,
        env={"PATH": "/usr/bin:/bin", "ANSIBLE_LOCAL_TEMP": str(path.parent / ".ansible"), "HOME": str(path.parent)},
    )
    hostvars = json.loads(out.stdout)["_meta"]["hostvars"]
    result = {}
    for host, variables in hostvars.items():
        data = {OURS.get(k, k): v for k, v in variables.items() if not k.startswith("ansible_") or k in OURS}
        for older, setting in OLDER.items():  # the older name wins, wherever it is set
            if older in variables:
                data[setting] = variables[older]
        result[host] = data
    return result


@pytest.mark.parametrize("layout", ["ini-file", "ini-dir", "yaml-file", "yaml-dir"])
def test_each_host_gets_the_settings_ansible_gives_it(tmp_path, layout):
    hosts = INI_HOSTS if layout.startswith("ini") else YAML_HOSTS
    name = "hosts" if layout == "ini-dir" else "hosts.ini" if layout == "ini-file" else "hosts.yml"
    inventory = write(tmp_path / "inventory", {name: hosts, **VARS})
    path = inventory if layout.endswith("dir") else inventory / name
    found = ours(path)
    assert found == ansibles(path)
    assert len(found) == (11 if layout.startswith("ini") else 7)


def test_the_precedence_is_ansibles(tmp_path):
    """all < parent < child, inline vars < group_vars/ files (all's too),
    then the host's line < host_vars/; sibling groups by priority, then name."""
    found = ours(write(tmp_path, {"hosts": INI_HOSTS, **VARS}))
    assert found["robot01"]["ros_domain_id"] == 12  # group_vars/robots over the inline [warehouse_a:vars]
    assert found["robot-a"]["ros_domain_id"] == 13  # group_vars/warehouse_b (deeper) over group_vars/robots
    assert found["alice-laptop"]["ros_domain_id"] == 11  # group_vars/all over [all:vars]
    assert found["robot02"]["ros_domain_id"] == 99 and found["robot02"]["ssh_user"] == "root"  # host_vars
    assert found["robot01"]["docker_users"] == ["ops", "ci"]  # a directory's files merge in name order
    yaml = ours(write(tmp_path / "y", {"hosts.yml": YAML_HOSTS, **VARS}) / "hosts.yml")
    assert yaml["robota"]["payload_stable_seconds"] == 21  # site_b's priority 10 puts it after site_c
    assert yaml["robot2"]["ros_domain_id"] == 97  # host_vars/robot2/b.yml after a.yml


def test_ranges_ports_and_older_names(tmp_path):
    found = ours(write(tmp_path, {"hosts": INI_HOSTS}))
    assert sorted(found) == [
        "alice-laptop",
        "robot-a",
        "robot-b",
        "robot-c",
        "robot01",
        "robot02",
        "robot03",
        "robot10",
        "robot12",
        "robot14",
        "robot7",
    ]
    assert found["robot7"]["ssh_hostname"] == "10.20.1.7"
    assert "ssh_port" not in found["robot7"]  # robot7:2222 is not its first listing: Ansible ignores the port
    assert found["robot7"]["ros_domain_id"] == 70  # the ungrouped line's settings still count
    yaml = ours(write(tmp_path / "y", {"hosts.yml": YAML_HOSTS}) / "hosts.yml")
    assert yaml["robot1"]["ssh_port"] == 2201 and yaml["robot9"]["ssh_port"] == 2222
    assert yaml["alice-laptop"]["ssh_hostname"] == "10.0.0.50"


def test_an_older_name_overriding_a_newer_one_is_a_note(tmp_path, capfd):
    fleet = load(write(tmp_path, {"hosts": INI_HOSTS}) / "hosts")
    assert fleet.notes == [
        f"{display(tmp_path / 'hosts')}:2: note: robot7: ansible_ssh_host ('10.20.1.7') wins over ssh_hostname "
        "('10.20.1.70'), as in Ansible",
        f"{display(tmp_path / 'hosts')}: note: ansible_become: Ansible's own, ignored here",
    ]


def problems(tmp_path: Path, files: dict[str, str], target: str = "") -> list[str]:
    root = write(tmp_path / "inv", files)
    try:
        load(root / target if target else root)
    except FleetError as error:
        return [line.removeprefix(display(root) + "/") for line in error.lines]
    return []


BASE = f"[all:vars]\npayload_image={IMAGE}\n"


@pytest.mark.parametrize(
    "text, line",
    [
        (
            "[robots]\nrobot1 x11_enabled=true\n",
            "hosts:2: robot1.x11_enabled: expected true or false, got 'true'; INI reads "
            "it as text, as Ansible does: write True or False",
        ),
        (
            "[robots]\nrobot1 docker_usres=['ops']\n",
            "hosts:2: robot1.docker_usres: unknown setting (did you mean 'docker_users'?)",
        ),
        ("[robots]\nrobot[3:1]\n", "hosts:2: 'robot[3:1]': host range [3:1] in 'robot[3:1]' must have begin <= end"),
        (
            "[robots]\nrobot[01:3]\n",
            "hosts:2: 'robot[01:3]': host range [01:3] in 'robot[01:3]': a zero-padded begin "
            "needs an end of the same width (01:03)",
        ),
        (
            '[robots]\nrobot1 "unclosed\n',
            "hosts:2: cannot read this host line: No closing quotation (an unclosed quote?)",
        ),
        (
            "[robots]\nrobot1 ansible_host\n",
            "hosts:2: robot1: expected key=value after the host name, got 'ansible_host'",
        ),
        (
            "[robots:varz]\n[robots]\nrobot1\n",
            "hosts:1: [robots:varz]: unknown section type 'varz' (a section is "
            "[group], [group:vars] or [group:children])",
        ),
        (
            "[robots]\nrobot1\n[ghost:vars]\nx=1\n",
            "hosts:3: [ghost:vars] names the group 'ghost', which is declared "
            "nowhere (add a [ghost] or [ghost:children] section)",
        ),
        (
            "[robots:children]\nsite\n[robots]\nrobot1\n",
            "hosts:2: [robots:children] names the group 'site', which is "
            "declared nowhere (add a [site] or [site:children] section)",
        ),
        (
            "[robots]\nrobot1\n[a:children]\nb\n[b:children]\na\n",
            "hosts:6: [b:children]: a is already above b (the groups would form a circle)",
        ),
        (
            "[robots]\nrobot1\n[robots:vars]\nros_domain_id\n",
            "hosts:4: [robots:vars]: expected key=value, got 'ros_domain_id'",
        ),
        (
            "[robots ]\nrobot1\n",
            "hosts:1: [robots ]: not a section header (no spaces inside the brackets; [group], "
            "[group:vars] or [group:children])",
        ),
        ("[site]\nrobot1\n", "hosts:2: robot1: in neither a robots nor a laptops group (groups: site)"),
    ],
)
def test_ini_mistakes_get_one_line_with_file_and_line(tmp_path, text, line):
    assert line in problems(tmp_path, {"hosts": text + BASE}, "hosts")


def test_vars_file_mistakes_name_the_file(tmp_path):
    assert problems(
        tmp_path,
        {
            "hosts": "[robots]\nrobot1\n" + BASE,
            "group_vars/robots.yml": "docker_usres: [ops]\n",
            "host_vars/robot1.yml": "- not a mapping\n",
            "group_vars/all/secrets.yml": "$ANSIBLE_VAULT;1.1;AES256\n6162\n",
        },
    ) == [
        "group_vars/all/secrets.yml: encrypted with ansible-vault, which robotfleet does not read: decrypt it "
        f"(ansible-vault decrypt {display(tmp_path / 'inv')}/group_vars/all/secrets.yml) or move the fleet's "
        "settings out of it",
        "host_vars/robot1.yml: expected a mapping of settings for the host robot1, got a list",
        "group_vars/robots.yml: robots.docker_usres: unknown setting (did you mean 'docker_users'?)",
    ]


def test_vars_files_that_are_not_read_are_notes(tmp_path):
    root = write(
        tmp_path / "inv",
        {
            "hosts": "[robots]\nrobot1\n" + BASE,
            "group_vars/robot.yml": "x: 1\n",
            "group_vars/robots/main.yml": "ros_domain_id: 5\n",
            "group_vars/robots.yml": "ros_domain_id: 6\n",
            "group_vars/robots.yml.orig": "x: 1\n",
            "host_vars/robot2.yml": "x: 1\n",
        },
    )
    fleet = load(root)
    shown = display(root)
    assert fleet.notes == [
        f"{shown}/group_vars/robot.yml: note: no group 'robot' in the inventory (did you mean 'robots'?); not read",
        f"{shown}/group_vars/robots.yml: note: not read: group_vars/robots is read for the group robots instead "
        "(Ansible reads the first of NAME/, NAME, NAME.yml, NAME.yaml, NAME.json); merge them",
        f"{shown}/group_vars/robots.yml.orig: note: not read: a vars file ends in .yml, .yaml or .json, or has none",
        f"{shown}/host_vars/robot2.yml: note: no host 'robot2' in the inventory (did you mean 'robot1'?); not read",
    ]
    assert dict(fleet.hosts("robots"))["robot1"]["ros_domain_id"] == 5


def test_a_vars_file_not_read_is_noted_with_the_errors_it_explains(tmp_path):
    """group_vars/robot.yml (not read) holds the payload image the robots
    then lack: its note comes with the error, not once every error is fixed
    (issue 39, item 10)."""
    root = write(
        tmp_path / "inv",
        {"hosts": "[robots]\nrobot1 ansible_host=127.0.0.1\n", "group_vars/robot.yml": f"payload_image: {IMAGE}\n"},
    )
    result = subprocess.run(
        [sys.executable, "-m", "robotfleet", "status", "inventories/robots.py"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
        env={"PATH": "/usr/bin:/bin", "ROBOT_FLEET": str(root), "HOME": str(tmp_path)},
    )
    lines = result.stderr.splitlines()
    note = (
        f"{display(root)}/group_vars/robot.yml: note: no group 'robot' in the inventory (did you mean "
        "'robots'?); not read"
    )
    assert result.returncode == 2, result.stderr
    assert note in lines and lines[-1] == "1 problem(s) in the fleet file; no host was contacted.", result.stderr
    assert any("robot1" in line and "payload_image" in line for line in lines), result.stderr
    with pytest.raises(FleetError) as error:
        load(root)
    assert error.value.notes == [note]


@pytest.mark.parametrize(
    "name, text, line",
    [
        (
            "inventory.sh",
            "#!/bin/sh\necho '{}'\n",
            "inventory.sh: a dynamic inventory script: robotfleet reads static "
            "inventories; write its output to a file: ansible-inventory -i {d}/inventory.sh --list -y > fleet.yaml",
        ),
        (
            "aws_ec2.yml",
            "plugin: amazon.aws.aws_ec2\nregions: [eu-west-1]\n",
            "aws_ec2.yml: an inventory plugin's "
            "configuration (plugin: 'amazon.aws.aws_ec2'): robotfleet reads static inventories; write the plugin's "
            "output to a file: ansible-inventory -i {d}/aws_ec2.yml --list -y > fleet.yaml",
        ),
        (
            "hosts.toml",
            "[robots.hosts]\nrobot1 = {}\n",
            "hosts.toml: a TOML inventory is not read here: convert it: "
            "ansible-inventory -i {d}/hosts.toml --list -y > fleet.yaml",
        ),
    ],
)
def test_what_ansible_reads_and_we_cannot_is_refused_saying_what_to_do(tmp_path, name, text, line):
    assert problems(tmp_path, {name: text}) == [line.format(d=display(tmp_path / "inv"))]


def test_an_inventory_directory_skips_what_ansible_skips(tmp_path):
    root = write(
        tmp_path / "inv",
        {
            "10-hosts": "[robots]\nrobot1\n",
            "20-more.yaml": "laptops: {hosts: {lap1: {x11_user: a}}}\n",
            "README.md": "# not an inventory [robots]\n",
            "ansible.cfg": "[defaults]\n",
            ".hidden": "[robots]\nrobot9\n",
            "old.bak": "[robots]\nrobot8\n",
            "more/group_vars/all.yml": "ros_domain_id: 5\n",
            "group_vars/all.yml": f"payload_image: {IMAGE}\n",
        },
    )
    fleet = load(root)
    assert [name for name, _ in fleet.hosts("robots")] == ["robot1"]
    assert [name for name, _ in fleet.hosts("laptops")] == ["lap1"]
    assert "ros_domain_id" not in dict(fleet.hosts("robots"))["robot1"]
    assert fleet.notes == [
        f"{display(root)}/more/group_vars: note: not read: Ansible reads group_vars/ and "
        "host_vars/ at the top of an inventory directory only"
    ]


@pytest.mark.parametrize(
    "pattern, names, port",
    [
        ("robot[01:03]", ["robot01", "robot02", "robot03"], None),
        ("robot[a:c]", ["robota", "robotb", "robotc"], None),
        ("robot[1:10:3]", ["robot1", "robot4", "robot7", "robot10"], None),
        ("robot[:2]", ["robot0", "robot1", "robot2"], None),
        ("r[1:2]-[a:b].lan", ["r1-a.lan", "r1-b.lan", "r2-a.lan", "r2-b.lan"], None),
        ("robot[01:02]:2222", ["robot01", "robot02"], 2222),
        ("robot7:22", ["robot7"], 22),
        ("robot7", ["robot7"], None),
    ],
)
def test_host_patterns_expand_as_ansible_expands_them(pattern, names, port):
    assert hostpattern.expand(pattern) == (names, port)


@pytest.mark.parametrize(
    "pattern", ["robot[1:2:0]", "robot[1:2:3:4]", "robot[1:]", "robot[a:5]", "robot[0:999999]", "robot[1:3", "robot7:"]
)
def test_host_patterns_ansible_refuses_are_refused(pattern):
    with pytest.raises(hostpattern.PatternProblem):
        hostpattern.expand(pattern)


@pytest.mark.parametrize(
    "text, value",
    [
        ("2222", 2222),
        ("True", True),
        ("true", "true"),
        ("FALSE", "FALSE"),
        ("['ops', 'ci']", ["ops", "ci"]),
        ("('a', 'b')", ["a", "b"]),
        ("'0755'", "0755"),
        ("0755", "0755"),
        ("1.10", 1.1),
        ("10-5", "10-5"),
        ("None", None),
        ("ops # a comment", "ops # a comment"),
        ("23 # a comment", 23),
        ("{'a': 1}", {"a": 1}),
        ("[" * 400 + "]" * 400, "[" * 400 + "]" * 400),
    ],
)
def test_ini_values_are_typed_as_ansible_types_them(text, value):
    assert ini.value(text) == value


def test_the_editors_schema_takes_host_patterns_and_ansibles_names():
    import jsonschema

    from robotfleet import deploy_roles
    from robotfleet.fleet import loader, schema

    validator = jsonschema.Draft7Validator(schema.fleet_schema(deploy_roles.registry()))
    assert list(validator.iter_errors(loader.load(YAML_HOSTS))) == []
    bad = loader.load("robots:\n  hosts:\n    'robot[1:': {}\n    'robot 7': {}\n")
    assert len(list(validator.iter_errors(bad))) == 2


def test_vault_values_are_ignored_in_ansibles_variables_and_refused_in_settings(tmp_path):
    vault = "!vault |\n  $ANSIBLE_VAULT;1.1;AES256\n  6162\n"
    files = {"hosts": "[robots]\nrobot1\n" + BASE, "group_vars/all.yml": f"ansible_become_password: {vault}"}
    assert problems(tmp_path, files) == []
    files["group_vars/robots.yml"] = f"x11_user: {vault}"
    files["host_vars/robot1.yml"] = 'docker_users: [ops, !vault "6162"]\n'

    assert problems(tmp_path, files) == [
        "group_vars/robots.yml: robots.x11_user: an ansible-vault value (!vault), which robotfleet "
        "does not decrypt: write the value, or keep it in a secret store",
        "host_vars/robot1.yml: robot1.docker_users[1]: expected a string, got an ansible-vault value (!vault)",
    ]
