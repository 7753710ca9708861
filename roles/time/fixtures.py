"""Test fixtures: what a successful run of the time role leaves on a host."""

import roles.time.plan as plan
from robotfleet.host.fixtures import file_state


def converged(play, host: str) -> None:
    data, snap = play.data, play.snapshot
    snap.packages["chrony"] = "1"
    snap.files[plan.CONF] = file_state(plan.chrony_conf(data))
    if not data.time_set_clock:
        snap.files[plan.DROP_IN] = file_state(plan.drop_in())
    snap.units[plan.UNIT] = ("enabled", "active")
