"""Roll robots back to their previous payload release.

    pyinfra inventories/robots.py rollback.py --limit robot2     # one robot
    pyinfra inventories/robots.py rollback.py --limit robots     # a group
    pyinfra inventories/robots.py rollback.py                    # the fleet

`current` and `previous` swap, the payload is brought up from the release
already on the robot (no download: it works offline) and checked healthy.
Refused while the update lock is held, unless --data payload_force=true.
"""

from pyinfra import host

from roles.payload import rollback_release

rollback_release(host.data)
