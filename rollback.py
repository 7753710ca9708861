"""Roll robots back to their previous payload release.

    pyinfra inventories/robots.py rollback.py --limit robot2     # one robot
    pyinfra inventories/robots.py rollback.py --limit robots     # a group
    pyinfra inventories/robots.py rollback.py                    # the fleet

`current` and `previous` swap, the payload is brought up from the release
already on the robot (no download: it works offline) and checked healthy.
All or nothing: if the previous release is not healthy, the swap is undone
and the release that ran before starts again (the host fails with why).
Refused while the update lock is held, unless --data payload_force=true.
"""

from pyinfra import host

from roles.payload import rollback_release

rollback_release(host.data)
