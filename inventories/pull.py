"""This robot converging itself in pull mode: the inventory its agent's
converge run uses (robotfleet/pull/robot/converge.py), never run by hand.

    ROBOT_FLEET=inventories/robots.yaml ROBOT_FLEET_HOST=robot1 ROBOT_PULL_DATA=run.json \\
        pyinfra -y inventories/pull.py deploy.py

The robot's entry of the release's fleet file (by name, in whichever group
it is), on pyinfra's @local connector, as root (no sudo), with the run's
own data on top: the images pinned to the release's digests, the tokens
of the locks the agent holds, and who the run is for.
"""

import json
import os
from pathlib import Path

from robotfleet.inventory import display_path, load_or_exit, refuse, require_checkout

require_checkout()

_missing = [name for name in ("ROBOT_FLEET", "ROBOT_FLEET_HOST") if not os.environ.get(name)]
if _missing:
    refuse([f"inventories/pull.py: {', '.join(_missing)} not set (the pull agent runs this inventory)"])
_path = Path(os.environ["ROBOT_FLEET"])
_name = os.environ["ROBOT_FLEET_HOST"]
_fleet = load_or_exit(_path)
_found = [(group, data) for group in ("robots", "laptops") for name, data in _fleet.hosts(group) if name == _name]
if not _found:
    refuse([f"{display_path(_path)}: no host named {_name!r}; the release is not for this robot"])
_group, _data = _found[0]
_data = {k: v for k, v in _data.items() if not k.startswith("ssh_")}
if os.geteuid() == 0:
    _data["_sudo"] = False  # the agent runs as root; a robot need not have sudo
if os.environ.get("ROBOT_PULL_DATA"):
    _extra = json.loads(Path(os.environ["ROBOT_PULL_DATA"]).read_text())
    for _setting, _file in _extra.pop("tokens", {}).items():
        _data[_setting] = Path(_file).read_text().strip()
    _data.update(_extra.get("data", {}))

globals()[_group] = [("@local", _data)]
