"""Where each value comes from (issue 39, item 6): a host's settings with the
group or host and file that set them, what they override, secrets masked;
the groups as ansible-inventory draws them; and a note wherever sibling
groups set one setting differently, saying which won and why (Ansible's
rule picks one silently).  Pure: fleets from text (tests/integration/
test_inventory_command.py runs the command on files, beside Ansible)."""

from __future__ import annotations

import json

from robotfleet.commands import inventoryview
from robotfleet.fleet import provenance
from tests.unit.harness import parse, registry

IMAGE = "reg.example.com/acme/ros-payload:1.4.2"
FLEET = f"""
all:
  vars: {{payload_image: "{IMAGE}", ssh_user: ops}}
  children:
    robots:
      vars: {{ros_domain_id: 2}}
      children:
        warehouse_a:
          vars: {{ssh_port: 2222, ros_domain_id: 3}}
          hosts:
            robot7: {{ansible_host: 10.20.1.7, payload_environment: {{DB_URL: "postgres://ros:s3cret@db/maps"}}}}
            robot8: {{address: 10.20.1.8}}
        lidar_bots:
          vars: {{ssh_port: 22, ros_domain_id: 3}}
          hosts:
            robot7:
            robot8:
        fast:
          vars: {{ansible_group_priority: 5, payload_stable_seconds: 9}}
          hosts:
            robot9: {{address: 10.20.1.9}}
        slow:
          vars: {{payload_stable_seconds: 60}}
          hosts:
            robot9:
    laptops:
      hosts:
        alice-laptop: {{address: 10.20.0.50, x11_user: alice}}
"""


def test_sibling_groups_that_disagree_get_a_note_naming_the_winner_and_why():
    notes = parse(FLEET).notes
    assert notes == [
        "f.yaml: note: robot7, robot8: ssh_port is group warehouse_a's, not lidar_bots's (sibling groups that set it "
        "differently; same depth and ansible_group_priority: warehouse_a sorts after lidar_bots by name, as in "
        "Ansible); set it on the host or give one group a higher ansible_group_priority",
        "f.yaml: note: robot9: payload_stable_seconds is group fast's, not slow's (sibling groups that set it "
        "differently; ansible_group_priority 5 over 1, as in Ansible); set it on the host or give one group a higher "
        "ansible_group_priority",
    ]


def test_a_child_group_overriding_its_parent_or_siblings_agreeing_is_no_note():
    fleet = parse(FLEET.replace("ssh_port: 22,", "ssh_port: 2222,").replace("seconds: 60", "seconds: 9"))
    assert fleet.notes == []  # ros_domain_id: robots' 2 under the children's 3, both 3: as meant


def test_each_value_names_whose_it_is_and_what_it_overrides():
    fleet = parse(FLEET)
    found = provenance.origins(fleet.tree, "robot7", inventoryview.written(registry()))
    assert [(o.who, o.value) for o in found["ssh_port"]] == [
        ("group lidar_bots", ("ssh_port", 22)),
        ("group warehouse_a", ("ssh_port", 2222)),
    ]
    assert [(o.who, o.value) for o in found["ssh_hostname"]] == [("host robot7", ("ansible_host", "10.20.1.7"))]
    lines = inventoryview.host_lines(fleet, "robot7", registry(), defaults=False)
    assert lines[0] == "robot7: a robot, in lidar_bots, robots, warehouse_a"
    rows = [line.split() for line in lines[1:]]
    assert ["ssh_port", "2222", "group", "warehouse_a", "(f.yaml)"] in rows
    assert ["over", "22", "group", "lidar_bots", "(f.yaml)"] in rows
    assert ["ssh_hostname", "10.20.1.7", "host", "robot7", "as", "ansible_host", "(f.yaml)"] in rows
    assert ["ros_domain_id", "3", "group", "warehouse_a", "(f.yaml)"] in rows
    assert ["over", "2", "group", "robots", "(f.yaml)"] in rows
    assert "s3cret" not in "\n".join(lines) and "postgres://ros:****@db/maps" in "\n".join(lines)
    with_defaults = inventoryview.host_lines(fleet, "robot7", registry(), defaults=True)
    assert any(line.split()[:3] == ["apt_lock_timeout", "300", "default"] for line in with_defaults)


def test_the_graph_and_the_list_are_ansible_inventorys():
    fleet = parse(FLEET)
    assert inventoryview.graph(fleet.tree, "all") == [
        "@all:",
        "  |--@ungrouped:",
        "  |--@robots:",
        "  |  |--@warehouse_a:",
        "  |  |  |--robot7",
        "  |  |  |--robot8",
        "  |  |--@lidar_bots:",
        "  |  |  |--robot7",
        "  |  |  |--robot8",
        "  |  |--@fast:",
        "  |  |  |--robot9",
        "  |  |--@slow:",
        "  |  |  |--robot9",
        "  |--@laptops:",
        "  |  |--alice-laptop",
    ]
    listed = inventoryview.listing(fleet, registry())
    assert "s3cret" not in listed
    data = json.loads(listed)
    assert data["all"] == {"children": ["ungrouped", "robots", "laptops"]}
    assert data["robots"] == {"children": ["warehouse_a", "lidar_bots", "fast", "slow"]}
    assert data["warehouse_a"] == {"hosts": ["robot7", "robot8"]}
    assert data["_meta"]["hostvars"]["robot7"]["ssh_port"] == 2222
    assert data["_meta"]["hostvars"]["robot7"]["payload_environment"] == {"DB_URL": "postgres://ros:****@db/maps"}
