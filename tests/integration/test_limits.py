"""--limit as operators write it (issue 28, item 6): a comma list, pyinfra's
patterns (a group, a glob on host names) and Ansible's &group and !host, in
pyinfra's deploys and in every robotfleet command; and an Ansible inventory
directory named by ROBOT_FLEET, with its group_vars/ and host_vars/, reaching
the connection (item 2).  Real processes and closed ports on 127.0.0.1: a
host the command selected is one that was dialled."""

from __future__ import annotations

import json
import re

import pytest

from robotfleet import selection
from tests.fixtures import PYINFRA
from tests.integration import sshserver
from tests.integration.operator_side import fleet, run


@pytest.fixture(autouse=True)
def key(client_key):
    return client_key


HOSTS = [
    ("robot1", {"robots", "site_a"}),
    ("robot2", {"robots", "site_a"}),
    ("robot3", {"robots", "site_b"}),
    ("lap1", {"laptops"}),
]
GROUPS = {"robots", "laptops", "site_a", "site_b"}


@pytest.mark.parametrize(
    "limits, chosen",
    [
        (["robot1,robot3"], ["robot1", "robot3"]),
        (["robot1", "robot3"], ["robot1", "robot3"]),
        (["robot*"], ["robot1", "robot2", "robot3"]),
        (["site_a,lap1"], ["robot1", "robot2", "lap1"]),
        (["robots,!robot2"], ["robot1", "robot3"]),
        (["!robot2"], ["robot1", "robot3", "lap1"]),
        (["robots,&site_a"], ["robot1", "robot2"]),
        (["robots,&site_a,!robot1"], ["robot2"]),
        ([" robot1 , robot2 ,"], ["robot1", "robot2"]),
    ],
)
def test_limits_select_as_pyinfra_and_ansible_do(limits, chosen):
    assert selection.resolve(limits, HOSTS, GROUPS)[0] == chosen
    assert selection.refusal(limits, "inv.py", HOSTS, GROUPS) is None


@pytest.mark.parametrize(
    "limits, line",
    [
        (
            ["robot1,bot-z"],
            "--limit bot-z: no host or group of inv.py matches (hosts: robot1, robot2, robot3, lap1; "
            "groups: laptops, robots, site_a, site_b); nothing was done",
        ),
        (["robots,!nobody"], "--limit nobody: no host or group of inv.py matches"),
        (["laptops,&site_a"], "--limit laptops,&site_a: selects no host of inv.py"),
        (
            ["~robot[12]"],
            "--limit ~robot[12]: regular expressions (~) are not supported; use a glob (robot*) or a "
            "group's name; nothing was done",
        ),
        (
            ["robots:!robot2"],
            "--limit robots:!robot2: separate patterns with commas (robots,laptops), not ':'; nothing was done",
        ),
    ],
)
def test_a_limit_that_cannot_select_is_refused_in_one_line(limits, line):
    assert selection.refusal(limits, "inv.py", HOSTS, GROUPS).startswith(line)


ANSIBLE_PATTERNS = [
    "all",
    "all,!robot04",
    "robots[0:2]",
    "robots[-1]",
    "robots[3:]",
    "robots[0:0]",
    "robots[1]",
    "robot*[1:2]",
    "all,!robots[0:3]",
    "robots,&robots[1:3],!robot03",
]


@pytest.mark.parametrize("limit", ANSIBLE_PATTERNS)
def test_all_and_subscripts_select_what_ansible_selects(tmp_path, limit):
    """Ansible's own InventoryManager reads the same hosts and the same
    pattern (its ':' where ours has ','; issue 39, item 5)."""
    from ansible.inventory.manager import InventoryManager
    from ansible.parsing.dataloader import DataLoader

    (tmp_path / "hosts").write_text("[robots]\nrobot0[1:5]\n\n[laptops]\nlap1\n")
    ansible = InventoryManager(loader=DataLoader(), sources=[str(tmp_path / "hosts")])
    hosts = [(f"robot0{i}", {"robots"}) for i in range(1, 6)] + [("lap1", {"laptops"})]
    theirs = [host.name for host in ansible.get_hosts(limit.replace(",", ":"))]
    assert theirs, limit
    assert selection.resolve([limit], hosts, {"robots", "laptops"})[0] == theirs


def dialled(output: str) -> list[str]:
    return sorted(set(re.findall(r"\[(robot\d)\] (?:unreachable: )?connection refused", output)))


@pytest.fixture
def three_dead(tmp_path):
    closed = sshserver.closed_port()
    return fleet(
        tmp_path, {f"robot{i}": {"address": "127.0.0.1", "ssh_port": closed} for i in (1, 2, 3)}, ssh_connect_retries=0
    )


@pytest.mark.parametrize(
    "options, chosen",
    [
        (["--limit", "robot1,robot3"], ["robot1", "robot3"]),
        (["--limit", "robots,!robot2"], ["robot1", "robot3"]),
        (["--exclude", "robot1,robot2"], ["robot3"]),
        (["--limit", "robot*", "--exclude", "robot3"], ["robot1", "robot2"]),
        (["--limit", "all,!robot2"], ["robot1", "robot3"]),
        (["--limit", "robots[1:]"], ["robot2", "robot3"]),
    ],
)
def test_pyinfra_deploys_take_the_same_limits(tmp_path, three_dead, options, chosen):
    result = run(three_dead, tmp_path, "-c", PYINFRA, "-y", "inventories/robots.py", "deploy.py", *options)
    assert result.returncode == 1, result.stderr[-2000:]
    assert dialled(result.stderr) == chosen, result.stderr[-2000:]


def test_a_bare_all_is_refused_by_pyinfra_deploys_in_one_line(tmp_path, three_dead):
    """pyinfra's inventories have no group all: it would match nothing and exit 0."""
    result = run(three_dead, tmp_path, "-c", PYINFRA, "-y", "inventories/robots.py", "deploy.py", "--limit", "all")
    ours = [x for x in result.stderr.splitlines() if not x.startswith("--> ")]
    assert (result.returncode, ours) == (
        2,
        [
            "--limit all: pyinfra has no group all; a deploy without --limit is "
            "every host (all,!HOST leaves some out); nothing was done"
        ],
    ), result.stderr


@pytest.mark.parametrize("limit", ["robots,!robot2", "all,!robot2", "robots[0],robots[-1]"])
@pytest.mark.parametrize("command", ["status", "rollout"])
def test_robotfleet_commands_take_the_same_limits(tmp_path, three_dead, command, limit):
    extra = ["--json"] if command == "status" else ["--dry"]
    result = run(three_dead, tmp_path, "-m", "robotfleet", command, "inventories/robots.py", "--limit", limit, *extra)
    assert result.returncode == 3, result.stderr[-2000:]
    assert dialled(result.stderr) == ["robot1", "robot3"], result.stderr
    if command == "status":
        assert [row["host"] for row in json.loads(result.stdout)] == ["robot1", "robot3"]


def test_an_inventory_directory_reaches_the_connection(tmp_path):
    """ROBOT_FLEET names the directory; the port each robot is dialled on
    comes from its group_vars/ and host_vars/."""
    first, second = sshserver.closed_port(), sshserver.closed_port()
    inventory = tmp_path / "inventory"
    (inventory / "group_vars").mkdir(parents=True)
    (inventory / "host_vars").mkdir()
    (inventory / "hosts").write_text("[robots]\nrobot[1:2] ansible_host=127.0.0.1\n")
    (inventory / "group_vars" / "all.yml").write_text(
        f"payload_image: reg.example.com/p:1\nansible_user: ops\nansible_port: {first}\nssh_connect_retries: 0\n"
        f"ssh_known_hosts_file: {tmp_path}/known_hosts\nssh_connect_timeout: 2\n"
    )
    (inventory / "host_vars" / "robot2.yml").write_text(f"ansible_ssh_port: {second}\n")
    result = run(inventory, tmp_path, "-m", "robotfleet", "status", "inventories/robots.py", "--json")
    assert result.returncode == 3, result.stderr
    errors = {row["host"]: row["error"] for row in json.loads(result.stdout)}
    assert errors == {
        "robot1": f"connection refused by 127.0.0.1:{first} (no SSH server listens on port {first})",
        "robot2": f"connection refused by 127.0.0.1:{second} (no SSH server listens on port {second})",
    }
