"""Test fixtures: what a successful run of the udev role leaves on a host."""

import roles.udev.rules as rules
from robotfleet.host.fixtures import file_state
from roles import udev


def converged(play, host: str) -> None:
    data, snap = play.data, play.snapshot
    for path, text in udev.vendor_rules(data).items():
        snap.files[path] = file_state(text)
    if data.udev_sensors:
        snap.files[data.udev_rules_file] = file_state(rules.render(data.udev_sensors))
