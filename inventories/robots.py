"""Fleet inventory: the hosts and their settings come from robots.yaml beside
this file (or the file named by $ROBOT_FLEET).  Every host's data is checked
before pyinfra connects anywhere."""

import os
from pathlib import Path

from robotfleet.inventory import load_or_exit, pyinfra_groups

_fleet = load_or_exit(Path(os.environ.get("ROBOT_FLEET") or Path(__file__).with_suffix(".yaml")))

# robots, laptops and the file's other groups (e.g. Ansible's children)
globals().update(pyinfra_groups(_fleet, __file__))
