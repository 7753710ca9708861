"""The scaling benchmark's inventory (tests/bench/scale.py writes its input).

$ROBOT_SCALE_HOSTS names a JSON file: the fleet file to read, the SSH key
and known_hosts, and each host's port on 127.0.0.1.  Hosts are checked and
handed to pyinfra as inventories/lab.py hands the lab's.
"""

import json
import os
from pathlib import Path

from robotfleet.inventory import parse_or_exit, pyinfra_groups


def _load():
    spec = json.loads(Path(os.environ["ROBOT_SCALE_HOSTS"]).read_text())
    fleet = parse_or_exit(Path(spec["fleet"]).read_text(), spec["fleet"])
    for hosts in fleet.groups.values():
        for name, data in hosts:
            data.update(
                ssh_hostname="127.0.0.1",
                ssh_port=spec["ports"][name],
                ssh_user=spec["ssh_user"],
                ssh_key=spec["ssh_key"],
                ssh_known_hosts_file=spec["known_hosts"],
                ssh_strict_host_key_checking="yes",
                ssh_allow_agent=False,
                ssh_look_for_keys=False,
            )
    return fleet


globals().update(pyinfra_groups(_load(), __file__))
