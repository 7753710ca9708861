"""The README's first command: bring the simulated fleet up and provision it
with exactly what a user runs against a real fleet, its robots running a
real ROS 1 graph (docs/guides/ros-payload.md: roscore, a talker and a
listener from Debian's ROS, tests/lab/ros_images.py)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from . import hosts, ros_graph, ros_images, state

ROOT = Path(__file__).resolve().parents[2]


def _beside_python(name: str) -> str:
    """``name`` from this interpreter's environment (.venv/bin/pyinfra), shown
    relative to the checkout: the venv's bin is usually not on PATH."""
    path = Path(sys.executable).parent / name
    if not path.exists():
        return name
    try:
        return str(path.relative_to(ROOT))
    except ValueError:
        return str(path)


def demo(prefix: str = "lab") -> int:
    lab = hosts.up(prefix)
    ros_images.ensure(lab)
    fleet = state.lab_dir(prefix) / "ros-fleet.yaml"
    fleet.write_text(ros_graph.lab_fleet())
    shown_fleet = os.path.relpath(fleet, ROOT)
    env = dict(os.environ, ROBOT_LAB_PREFIX=prefix, ROBOT_LAB_FLEET=str(fleet))
    pyinfra, python = _beside_python("pyinfra"), _beside_python("python")
    command = [pyinfra, "-y", "inventories/lab.py", "deploy.py"]
    print(f"\n$ ROBOT_LAB_PREFIX={prefix} ROBOT_LAB_FLEET={shown_fleet} {' '.join(command)}\n", flush=True)
    code = subprocess.run(command, cwd=ROOT, env=env).returncode  # a relative path runs from cwd
    robot = next(h for h in lab["hosts"] if h["group"] == "robots")
    key = os.path.relpath(lab["ssh_key"], ROOT)
    known = os.path.relpath(lab["known_hosts"], ROOT)
    print(
        f"""
The simulated fleet '{prefix}' is {"provisioned" if code == 0 else "up, but the run FAILED (see above)"}.

The ROS graph on {robot["name"]} (roscore, a talker, a listener; the fleet file: {shown_fleet}):
  docker exec {robot["container"]} docker exec robot-payload-roscore-1 rostopic echo -n 3 /chatter

Look inside a robot:
  ssh -i {key} -o UserKnownHostsFile={known} -p {robot["port"]} ops@127.0.0.1
  docker exec -it {robot["container"]} bash        # then: systemctl status robot-payload; docker ps; ls /var/log/ros
Fleet status:
  ROBOT_LAB_PREFIX={prefix} ROBOT_LAB_FLEET={shown_fleet} {python} -m robotfleet status inventories/lab.py
Run again (changes nothing):
  ROBOT_LAB_PREFIX={prefix} ROBOT_LAB_FLEET={shown_fleet} {pyinfra} -y inventories/lab.py deploy.py
Stop the lab:
  {python} -m tests.lab down --prefix {prefix}
"""
    )
    return code


if __name__ == "__main__":
    sys.exit(demo(*sys.argv[1:2]))
