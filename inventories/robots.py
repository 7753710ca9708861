"""Fleet inventory: the hosts and their settings come from robots.yaml beside
this file.  Every host's data is checked before pyinfra connects anywhere."""

from pathlib import Path

from roles.fleet import load_or_exit

_fleet = load_or_exit(Path(__file__).with_suffix(".yaml"))

robots = _fleet.hosts("robots")
laptops = _fleet.hosts("laptops")
