"""The engine's own settings: how to reach a host (pyinfra's SSH connector
data), how long apt waits for its lock, rollout canaries.  Pull mode's are
beside them (pull_mode.py)."""

from __future__ import annotations

from robotfleet import checkers as c
from robotfleet import value_kinds as v
from robotfleet.role import UNSET, Setting

# Keys the fleet file may use that are not settings of their own: address,
# and the connection variables of an Ansible inventory.
# Ansible's older names: where a host has an older and a newer name for the
# same thing (in any of its layers), the older one wins, as Ansible's ssh
# connection plugin has it (robotfleet/fleet/validate.py resolve_older_names).
OLDER_NAMES = {
    "ansible_ssh_host": "ssh_hostname",
    "ansible_ssh_user": "ssh_user",
    "ansible_ssh_port": "ssh_port",
    "ansible_ssh_private_key_file": "ssh_key",
}
ALIASES = {
    "address": "ssh_hostname",
    "ansible_host": "ssh_hostname",
    "ansible_user": "ssh_user",
    "ansible_port": "ssh_port",
    "ansible_private_key_file": "ssh_key",
    **OLDER_NAMES,
}

SETTINGS = (
    Setting(
        "ssh_hostname",
        UNSET,
        v.address,
        "The address SSH connects to (write it as address:); default: the host's name.",
    ),
    Setting("ssh_user", UNSET, v.user_name, "The SSH user (sudo runs every step); default: yours."),
    Setting("ssh_port", 22, c.integer(1, 65535), "The port sshd listens on."),
    Setting("ssh_key", UNSET, v.local_path, "Private key file on this machine; default: your agent and ~/.ssh keys."),
    Setting(
        "ssh_known_hosts_file",
        "inventories/known_hosts",
        v.local_path,
        "known_hosts file for strict host key checking (relative to the checkout).",
    ),
    Setting(
        "ssh_strict_host_key_checking",
        "yes",
        c.string(choices=("yes", "accept-new", "no")),
        "yes refuses unknown or changed host keys; accept-new trusts on first use; no disables checking.",
    ),
    Setting(
        "ssh_revoked_host_keys",
        None,
        c.optional(v.local_path),
        "A KRL (ssh-keygen -k) on this machine: host keys and certificates it revokes are refused; null: none.",
    ),
    Setting(
        "ssh_connect_timeout",
        10,
        c.integer(1, 600),
        "Seconds to reach a host, retries included: TCP connect, SSH greeting and login each give up "
        "after this, and a retry gets what is left of it.",
    ),
    Setting(
        "ssh_connect_retries",
        1,
        c.integer(0, 100),
        "Reconnects after a refused, reset or dropped connection (a flaky link) while "
        "ssh_connect_timeout leaves at least a second; never after a host key, login or non-SSH answer.",
    ),
    Setting("ssh_connect_retry_min_delay", 1, c.integer(0, 600), "Seconds before a reconnect, at least."),
    Setting("ssh_connect_retry_max_delay", 2, c.integer(0, 600), "Seconds before a reconnect, at most."),
    Setting(
        "ssh_keepalive_interval",
        15,
        c.integer(1, 3600),
        "Seconds without traffic on a connection before an SSH keepalive asks the host to answer "
        "(OpenSSH's ServerAliveInterval; for the agent's own git on a pull robot too).",
    ),
    Setting(
        "ssh_keepalive_count_max",
        3,
        c.integer(1, 100),
        "Intervals a keepalive may go unanswered before the connection is given up and the host fails "
        "naming the frozen link: by default a link silent for a minute.",
    ),
    Setting(
        "apt_lock_timeout",
        300,
        c.integer(0, 86400),
        "Seconds apt waits in all for the apt/dpkg locks another process holds, then the host fails naming it.",
    ),
    Setting(
        "rollout_canary",
        False,
        c.boolean,
        "This robot is updated in a rollout's first wave (else the first --canary N robots are).",
    ),
)
