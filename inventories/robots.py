"""Fleet inventory: the hosts and their settings come from robots.yaml beside
this file (or the file named by $ROBOT_FLEET).  Every host's data is checked
before pyinfra connects anywhere."""

import os
from pathlib import Path

from engine.inventory import load_or_exit

_fleet = load_or_exit(Path(os.environ.get("ROBOT_FLEET") or Path(__file__).with_suffix(".yaml")))

robots = _fleet.hosts("robots")
laptops = _fleet.hosts("laptops")
