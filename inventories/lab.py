"""The simulated fleet started by `python3 -m tests.lab up`.

Hosts and settings come from lab.yaml (or $ROBOT_LAB_FLEET); the running lab
(.lab/<prefix>/state.json, prefix from $ROBOT_LAB_PREFIX, default "lab")
supplies the SSH ports, the lab key and known_hosts, the registry (@registry@
as the hosts reach it, @registry_local@ as this machine does) and the Docker
CE mirror.  Host keys are checked strictly against the lab's known_hosts,
like a real fleet ($ROBOT_LAB_KNOWN_HOSTS names another file: first contact
starts from an empty one, tests/e2e/test_enroll.py).  $ROBOT_LAB_VIA (JSON,
host -> port) reaches hosts through a bad link on 127.0.0.1 instead
(tests/lab/linkproxy.py ``through``, which writes the known_hosts to use).
"""

import json
import os
from pathlib import Path

from robotfleet.inventory import parse_or_exit, pyinfra_groups, refuse

_ROOT = Path(__file__).resolve().parent.parent
_PREFIX = os.environ.get("ROBOT_LAB_PREFIX", "lab")
_STATE = _ROOT / ".lab" / _PREFIX / "state.json"
_FLEET = Path(os.environ.get("ROBOT_LAB_FLEET") or Path(__file__).with_suffix(".yaml"))


def _mirror_fingerprint(state):
    fingerprint = state.get("mirror_fingerprint")
    if fingerprint:
        return fingerprint
    for candidate in (Path(state["mirror_dir"]), Path(state["mirror_dir"]).parent):
        manifest = candidate / "manifest.json"
        if manifest.exists():
            return json.loads(manifest.read_text())["fingerprint"]
    refuse([f"{_STATE}: the lab has no Docker CE mirror; run python3 -m tests.lab up"])


def _load():
    if not _STATE.exists():
        refuse([f"no lab '{_PREFIX}' is running ({_STATE} missing); start it with: python3 -m tests.lab up"])
    state = json.loads(_STATE.read_text())
    text = _FLEET.read_bytes()
    try:
        text = text.decode()
    except UnicodeDecodeError:
        pass  # parse() says where, in one line
    for key, value in (
        {}
        if isinstance(text, bytes)
        else {
            "@registry_local@": state["registry_local"],  # the registry as this machine reaches it (push)
            "@registry@": state["registry"],
            "@mirror@": state["mirror_url"],
            "@mirror_fingerprint@": _mirror_fingerprint(state),
        }.items()
    ):
        text = text.replace(key, value)
    ports = {h["name"]: h["port"] for h in state["hosts"]}
    via = json.loads(os.environ.get("ROBOT_LAB_VIA") or "{}")
    fleet = parse_or_exit(text, os.path.relpath(_FLEET), source=f"{_FLEET}@{_STATE}")
    groups = {}
    for group, hosts in fleet.groups.items():
        groups[group] = []
        for name, data in hosts:
            if name not in ports:
                continue  # declared but not started (e.g. `up --robots 2`)
            data.update(
                ssh_hostname="127.0.0.1",
                ssh_port=via.get(name, ports[name]),
                ssh_user=state.get("ssh_user", "ops"),
                ssh_key=state["ssh_key"],
                ssh_known_hosts_file=os.environ.get("ROBOT_LAB_KNOWN_HOSTS") or state["known_hosts"],
                ssh_strict_host_key_checking="yes",
                ssh_allow_agent=False,
                ssh_look_for_keys=False,
            )
            groups[group].append((name, data))
    fleet.groups = groups
    fleet.subgroups = {group: [h for h in hosts if h in ports] for group, hosts in fleet.subgroups.items()}
    return fleet


globals().update(pyinfra_groups(_load(), __file__))
