"""roles/time: robots and laptops on the fleet's time source with chrony.

Multi-machine ROS needs one clock: tf lookups and bag timestamps across
machines fail without it.  Opt-in: the role runs where time_servers is set
or time_serve is true.  chrony.conf is written whole (checked with chronyd
-p where chrony has it) and chrony restarted only when it or the unit's
drop-in changed.  Installing chrony removes another time daemon
(systemd-timesyncd, ntp, ...): the packages conflict.  roles/time/README.md
says more.
"""

from __future__ import annotations

from pyinfra.api import deploy
from pyinfra.operations.util import any_changed

import roles.time.plan as plan
import roles.time.settings as settings
from robotfleet.host import apt, operations
from robotfleet.host.snapshot import SnapshotQuery
from robotfleet.role import Play, Role

CAPABILITIES_PROBE = "time_capabilities"


def runs_on(data) -> bool:
    return bool(data.time_servers) or data.time_serve is True


def declare_reads(data, query: SnapshotQuery) -> None:
    query.packages |= {"chrony", *plan.OTHER_DAEMONS}
    query.files |= {plan.CONF, plan.DROP_IN}
    query.units.add(plan.UNIT)
    query.probes[CAPABILITIES_PROBE] = "sed -n 's/^CapBnd:[[:space:]]*//p' /proc/1/status"


@deploy("Time (chrony)")
def chrony(play: Play):
    data, snap = play.data, play.snapshot
    if data.time_set_clock and plan.can_set_clock(snap.probes.get(CAPABILITIES_PROBE, "")) is False:
        operations.fail(
            name="Check that chrony may set the clock",
            message="time_set_clock: this host cannot set its clock (no CAP_SYS_TIME: a container?); "
            "set time_set_clock: false to track and serve time without setting it",
        )
        return
    others = plan.replaced(snap.packages)
    apt.apt_install(
        name="Install chrony" + (f" (replaces {', '.join(others)})" if others else ""),
        packages=["chrony"],
        installed=snap.packages,
    )
    changes = [
        operations.file(
            name=f"Write {plan.CONF}",
            path=plan.CONF,
            content=plan.chrony_conf(data),
            current=snap.files.get(plan.CONF),
            validate=plan.VALIDATE,
        )
    ]
    if data.time_set_clock:
        unit_changed = operations.absent(
            name="chrony may set the clock (no -x drop-in)",
            paths=[plan.DROP_IN],
            present=snap.files,
        )
    else:
        unit_changed = operations.file(
            name="chrony never sets the clock (-x, drop-in)",
            path=plan.DROP_IN,
            content=plan.drop_in(),
            current=snap.files.get(plan.DROP_IN),
        )
    changes.append(unit_changed)
    operations.run(name="Reload systemd units", script="systemctl daemon-reload", _if=unit_changed.did_change)
    operations.run(
        name="Restart chrony with the new configuration",
        script=f"systemctl restart {plan.UNIT}",
        _if=any_changed(*changes),
    )
    operations.service(
        name="chrony enabled and running",
        unit=plan.UNIT,
        enabled_now=snap.unit_enabled(plan.UNIT),
        active_now=snap.unit_active(plan.UNIT),
    )


ROLE = Role(
    name="time",
    doc="Robots and laptops on the fleet's time source with chrony (and hosts that serve it to the others).",
    settings=settings.SETTINGS,
    runs_on=runs_on,
    reads=declare_reads,
    steps=chrony,
    rules=settings.rules,
)
