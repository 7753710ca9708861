"""An Ansible inventory as operators keep it, for the tests that read one
(test_ansible_dirs.py: by robotfleet and by Ansible itself;
test_inventory_command.py: `robotfleet inventory` on it): the warehouse
fleet in INI and YAML, its group_vars/ and host_vars/, and ansible-inventory
from ansible-core (the test extra)."""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

IMAGE = "reg.example.com/acme/ros-payload:1.4.2"
ANSIBLE_INVENTORY = shutil.which("ansible-inventory", path=str(Path(sys.executable).parent))

INI_HOSTS = f"""\
# the warehouse fleet, as the Ansible team keeps it
robot7 ros_domain_id=70
[robots:children]
warehouse_a
warehouse_b

[warehouse_a]
robot[01:03] ansible_host=10.20.1.1
robot7:2222 ansible_ssh_host=10.20.1.7 ansible_host=10.20.1.70

[warehouse_b]
robot-[a:c]
robot[10:14:2]   # every second one

[warehouse_a:vars]
ros_domain_id=3
payload_stable_seconds = 7

[robots:vars]
ros_domain_id=2
docker_users=['ops']

[laptops]
alice-laptop ansible_host=10.20.0.50 ansible_user=alice x11_user=alice

[all:vars]
ansible_user=ops
ansible_become=True
payload_image={IMAGE}
ros_domain_id=1
"""

YAML_HOSTS = f"""\
all:
  vars:
    ansible_user: ops
    ansible_python_interpreter: /usr/bin/python3
    payload_image: {IMAGE}
  children:
    robots:
      vars: {{ros_domain_id: 2}}
      children:
        site_a:
          hosts:
            robot[1:3]: {{ansible_ssh_port: 2201}}
            robot9:2222: {{ansible_host: 10.0.0.9}}
        site_b:
          vars: {{ansible_group_priority: 10, payload_stable_seconds: 21}}
          hosts:
            robot[a:b]:
        site_c:
          vars: {{payload_stable_seconds: 22}}
          hosts:
            robota:
    laptops:
      hosts:
        alice-laptop: {{ansible_ssh_host: 10.0.0.50, x11_user: alice}}
"""

VARS = {
    "group_vars/all.yml": "ros_domain_id: 11\npayload_autostart: true\n",
    "group_vars/robots/main.yml": "ros_domain_id: 12\n",
    "group_vars/robots/users": "docker_users: [ops, ci]\n",
    "group_vars/warehouse_b.yaml": "ros_domain_id: 13\n",
    "group_vars/site_a.json": '{"payload_stable_seconds": 9}\n',
    "host_vars/robot02.yml": "ros_domain_id: 99\nansible_ssh_user: root\n",
    "host_vars/robot2/a.yml": "ros_domain_id: 98\n",
    "host_vars/robot2/b.yml": "ros_domain_id: 97\n",
}


def write(root: Path, files: dict[str, str]) -> Path:
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return root


def display(path: Path) -> str:
    from robotfleet.fleet.sources import display_path

    return display_path(path)
