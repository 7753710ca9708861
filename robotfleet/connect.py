"""pyinfra's SSH connector with what first contact with a fleet needs.

Every host of an inventory built by robotfleet/inventory.py is ``@fleet/<name>``,
this connector (registered in pyproject.toml's pyinfra.connectors entry
points), so the pyinfra CLI, status and rollout connect the same way:

- one line per host that cannot be reached, with the reason in words
  (refused, timed out, not an SSH server, authentication failed for user U
  with key K, unknown or changed host key with the file and the command that
  fixes it), and no paramiko traceback;
- bounded: ``ssh_connect_timeout`` bounds reaching a host, retries
  included: each of the TCP connect, the SSH greeting and authentication
  gives up after it, and a refused, reset or dropped connection is tried
  again (``ssh_connect_retries``) only while the time left allows, so that
  a host is given up within that time (plus the retry delay) whatever
  fails; a host key, authentication or non-SSH answer, which would fail the
  same way, is never tried again; the delay before a retry lets other hosts
  run (time.sleep, patched by gevent, looked up when it is called);
- a connection that stops answering ends (robotfleet/keepalive.py): a
  keepalive after ``ssh_keepalive_interval`` seconds without traffic,
  ``ssh_keepalive_count_max`` of them unanswered end it, and the command
  that waited fails its host with one line naming the frozen link (a
  connection the host or the link closed during a command likewise), so one
  robot's frozen link never holds the run, status or a rollout;
- an idle connection wakes its paramiko thread every few seconds, not ten
  times a second (idle_wakeup below);
- a host's key is checked by the fleet's policy (robotfleet/hostkey_policy.py:
  the fleet's known_hosts with ``@cert-authority`` and ``@revoked`` lines,
  accept-new writing a key once); the wording of each reason is
  robotfleet/reasons.py's, but for the ones only this connector knows
  (host keys, authentication).

Jump hosts and ssh_config (ProxyJump, IdentityFile, ...) keep pyinfra's
behaviour: only the target's connection is handled here.
"""

from __future__ import annotations

import getpass
import logging
import os
import shlex
import time
from random import uniform

from gevent import monkey
from paramiko import AuthenticationException, BadHostKeyException, SSHException
from paramiko.agent import Agent
from paramiko.ssh_exception import BadAuthenticationType
from pyinfra.api.exceptions import ConnectError, PyinfraError
from pyinfra.connectors import ssh
from pyinfra.connectors.ssh_util import _patch_paramiko_sk_key_support
from pyinfra.connectors.sshuserclient import client as sshuserclient
from pyinfra.connectors.util import CommandOutput, OutputLine

from robotfleet import hostkeys, keepalive
from robotfleet.hostkey_policy import FleetKnownHosts, FleetPolicy, HostKeyCheck, RefusedHostKey, UnknownHostKey
from robotfleet.reasons import closed_during_command, frozen, greeting_seen, network_reason, replace_advice

CONNECTOR = "fleet"
PARAMIKO_LOG = "robotfleet.connect.paramiko"
# paramiko logs every failed handshake with a traceback from its transport
# thread; the reason is told once, in words, by the host's line instead.
logging.getLogger(PARAMIKO_LOG).addHandler(logging.NullHandler())
logging.getLogger(PARAMIKO_LOG).propagate = False
DEFAULT_KEYS = ("id_rsa", "id_ecdsa", "id_ed25519", "id_dsa")  # what paramiko looks for in ~/.ssh
# paramiko's transport thread reads with a 0.1 s timeout, then looks for a close, a keepalive or a rekey:
# a thousand connections waiting in one operator woke 10,000 times a second (tests/bench/SCALE.md).
IDLE_WAKEUP_SECONDS = 5.0


# The inventory file this process loaded (set by robotfleet/inventory.py), for
# the command that fixes a host key.
INVENTORY = "INVENTORY"


def names(hosts: list[tuple[str, dict]], inventory: str | None = None) -> list[tuple[str, dict]]:
    """Inventory entries for this connector: (``@fleet/name``, data)."""
    global INVENTORY
    if inventory:
        INVENTORY = os.path.relpath(inventory) if os.path.isabs(inventory) else inventory
    return [(f"@{CONNECTOR}/{name}", data) for name, data in hosts]


def enroll_command(host: str) -> str:
    return f"robotfleet enroll {shlex.quote(INVENTORY)} --limit {shlex.quote(host)}"


class Client(sshuserclient.SSHClient, FleetKnownHosts):
    def __init__(self, check: HostKeyCheck | None = None):
        super().__init__()
        self.check = check

    def parse_config(self, hostname, initial_cfg=None, ssh_config_file=None, strict_host_key_checking=None):
        parsed = list(super().parse_config(hostname, initial_cfg, ssh_config_file, strict_host_key_checking))
        parsed[5] = 0  # ssh_config's ServerAliveInterval: the fleet's keepalives (Watch) replace it
        if self.check is not None:
            parsed[3] = FleetPolicy(self.check)
            parsed[4] = ()  # the fleet's known_hosts is read by the policy, not by paramiko
        return tuple(parsed)


class Data(ssh.ConnectorData):
    ssh_connect_timeout: int
    ssh_revoked_host_keys: str | None
    ssh_keepalive_interval: int
    ssh_keepalive_count_max: int


class FleetConnector(ssh.SSHConnector):
    """pyinfra's SSH connector; what differs is in the module's doc."""

    data_cls = Data
    data_meta = {
        **ssh.connector_data_meta,
        "ssh_connect_timeout": ssh.DataMeta("Seconds to connect, in all", 10),
        "ssh_revoked_host_keys": ssh.DataMeta("A KRL file of revoked host keys and certificates", None),
        "ssh_keepalive_interval": ssh.DataMeta("Seconds without traffic before a keepalive", 15),
        "ssh_keepalive_count_max": ssh.DataMeta("Unanswered keepalives that end the connection", 3),
    }

    @staticmethod
    def make_names_data(name):
        yield name, {}, []

    def timeout(self) -> int:
        return self.data["ssh_connect_timeout"] or self.state.config.CONNECT_TIMEOUT

    def attempt_timeout(self) -> float:
        """This attempt's limit for each of connect, greeting and login: the
        timeout, or on a retry what is left of it."""
        return getattr(self, "_attempt_timeout", None) or self.timeout()

    watch: keepalive.Watch | None = None
    unreached: str | None = None  # why the last connect failed, in words

    def make_paramiko_kwargs(self):
        kwargs = super().make_paramiko_kwargs()
        limit = self.attempt_timeout()
        kwargs.update(timeout=limit, banner_timeout=limit, auth_timeout=limit)
        return kwargs

    def connect(self) -> None:
        _patch_paramiko_sk_key_support()
        retries = allowed = self.data["ssh_connect_retries"]
        started = time.monotonic()
        self._attempt_timeout = None
        attempts = 0
        while True:
            self._attempt_started = time.monotonic()
            attempts += 1
            try:
                return self._connect()
            except Exception as error:  # every way a connection fails becomes one line
                reason, transient = self.explain(error)
            if self.client is not None:
                self.client.close()
            delay = uniform(self.data["ssh_connect_retry_min_delay"], self.data["ssh_connect_retry_max_delay"])
            left = self.timeout() - (time.monotonic() - started) - delay
            if not transient or retries <= 0 or left < 1:
                reason += tries(attempts, allowed, self.timeout(), transient and retries > 0)
                self.unreached = reason  # robotfleet deploy's exit code: the network's, or a refusal
                raise ConnectError(reason)
            retries -= 1
            self._attempt_timeout = left
            time.sleep(delay)

    def _connect(self) -> None:
        kwargs = self.make_paramiko_kwargs()
        self.kwargs = kwargs
        hostname = kwargs.pop("hostname")
        self.client = Client(self.host_key_check(kwargs))
        self.client.set_log_channel(PARAMIKO_LOG)
        try:
            self.client.connect(hostname, **kwargs)
        except SSHException as error:
            if not self._retry_paramiko_agent_keys(hostname, kwargs, error):
                raise
        transport = self.client.get_transport()
        if transport is None:
            return
        interval = self.data["ssh_keepalive_interval"]
        self.watch = keepalive.Watch(transport, interval, self.data["ssh_keepalive_count_max"])
        wakeup = idle_wakeup(interval, monkey.is_module_patched("socket"))
        if wakeup is not None:
            transport.sock.settimeout(wakeup)

    def run_shell_command(self, command, print_output=False, print_input=False, **arguments):
        """pyinfra's; a command that failed because the connection ended
        under it (frozen, or closed by the host or the link) gets the
        reason as its last line of stderr: pyinfra prints it with the host's
        name, status shows it."""
        try:
            ok, output = super().run_shell_command(command, print_output, print_input, **arguments)
        except (OSError, EOFError, SSHException) as error:  # the command or its stdin could not be sent (Frozen too)
            reason = self.lost(error)
            if reason is None:
                raise
            ok, output = False, CommandOutput([])
        else:
            reason = None if ok else self.lost()
        if reason is not None:
            output.combined_lines.append(OutputLine("stderr", reason))
            if print_output:  # pyinfra printed the command's lines as they came, and prints none at its failure
                self.host.log_styled(reason, fg="red", log_func=logging.getLogger("pyinfra").error)
        return ok, output

    def lost(self, error: BaseException | None = None) -> str | None:
        """Why the connection ended under a command (``error``: what the
        command raised, if it did), when it has (None: it is up)."""
        transport = self.client.get_transport() if self.client is not None else None
        if transport is None or transport.is_active():
            return None
        address, port = self.where()
        stopped = self.watch.frozen if self.watch is not None else None
        if stopped is not None:
            return frozen(address, port, stopped.seconds, stopped.interval, stopped.count_max)
        # paramiko hands its transport's error to the first caller that asks, then forgets it
        return closed_during_command(address, port, transport.saved_exception or error)

    def host_key_check(self, kwargs: dict) -> HostKeyCheck | None:
        """The fleet's host key checking (yes, accept-new), taking the
        known_hosts file from pyinfra's arguments; None: pyinfra's own (no)."""
        strict = kwargs.get("_pyinfra_ssh_strict_host_key_checking")
        if strict not in ("yes", "accept-new"):
            return None
        known = os.path.expanduser(kwargs.pop("_pyinfra_ssh_known_hosts_file", None) or "~/.ssh/known_hosts")
        revoked = self.data["ssh_revoked_host_keys"]
        return HostKeyCheck(
            known,
            os.path.expanduser(revoked) if revoked else None,
            kwargs.get("username") or self.data["ssh_user"],
            self.timeout(),
            strict == "accept-new",
        )

    # -- reasons, in words ---------------------------------------------------

    def where(self) -> tuple[str, int]:
        config = getattr(self.client, "_ssh_config", None) or {}
        address = self.data["ssh_hostname"] or self.host.name
        return address, int(config.get("port") or self.data["ssh_port"] or 22)

    def explain(self, error: Exception) -> tuple[str, bool]:
        """(one line saying why, whether trying again may help)."""
        address, port = self.where()
        known_hosts = self.data["ssh_known_hosts_file"] or "~/.ssh/known_hosts"
        if isinstance(error, UnknownHostKey):
            return (
                f"unknown host key: {error.entry} is not in {known_hosts} (ssh_strict_host_key_checking: yes); "
                f"check and enroll it: {enroll_command(self.host.name)}"
            ), False
        if isinstance(error, RefusedHostKey):
            return error.reason, False
        if isinstance(error, BadHostKeyException):
            return (
                f"host key CHANGED: {known_hosts} has {hostkeys.fingerprint(error.expected_key)} for "
                f"{hostkeys.entry(address, port)}, the host offers {hostkeys.fingerprint(error.key)}; refused "
                f"({replace_advice(INVENTORY, self.host.name)})"
            ), False
        if isinstance(error, PyinfraError):  # e.g. the ssh_key file is missing or unreadable
            return f"cannot connect: {error}", False
        if isinstance(error, AuthenticationException) or "No authentication methods available" in str(error):
            return self.auth_reason(error), False
        elapsed = time.monotonic() - getattr(self, "_attempt_started", time.monotonic())
        transport = self.client.get_transport() if self.client is not None else None
        return network_reason(error, address, port, self.attempt_timeout(), elapsed, greeting_seen(transport))

    def auth_reason(self, error: Exception) -> str:
        kwargs = getattr(self, "kwargs", {})
        config = getattr(self.client, "_ssh_config", None) or {}
        user = config.get("username") or self.data["ssh_user"] or getpass.getuser()
        tried = self.keys_offered(config)
        accepts = ""
        if isinstance(error, BadAuthenticationType) and error.allowed_types:
            accepts = f" (the server accepts: {', '.join(error.allowed_types)})"
        if not tried and "password" not in kwargs:
            return (
                f"authentication failed for user {user}: no key to offer (ssh_key is not set, no SSH agent key, "
                f"no key in ~/.ssh); set ssh_key to the fleet's private key"
            )
        return f"authentication failed for user {user} with {' and '.join(tried) or 'a password'}{accepts}"

    def keys_offered(self, config: dict) -> list[str]:
        if self.data["ssh_key"]:
            return [f"key {self.data['ssh_key']}"]
        tried = []
        identity = config.get("key_filename")
        if identity:
            tried.append("key " + (identity if isinstance(identity, str) else ", ".join(identity)))
        if self.data["ssh_allow_agent"]:
            try:
                count = len(Agent().get_keys())
            except Exception:  # no agent, or one that does not answer
                count = 0
            if count:
                tried.append(f"the SSH agent's {count} key(s)")
        if self.data["ssh_look_for_keys"]:
            found = [f"~/.ssh/{name}" for name in DEFAULT_KEYS if os.path.exists(os.path.expanduser(f"~/.ssh/{name}"))]
            if found:
                tried.append("key " + ", ".join(found))
        return tried


def tries(attempts: int, retries: int, timeout: float, time_up: bool) -> str:
    """What a connection failure's line adds about ssh_connect_retries: how
    often the host was tried, and why not again when the time ran out first
    ("": tried once, as asked, or for a reason a retry would not change)."""
    if attempts > 1:
        more = f", ssh_connect_timeout: {timeout:.0f} s spent" if time_up else ""
        return f" (tried {attempts} times: ssh_connect_retries: {retries}{more})"
    if time_up:
        return f" (not tried again: ssh_connect_timeout: {timeout:.0f} s spent; ssh_connect_retries: {retries})"
    return ""


def idle_wakeup(keep_alive: int, gevent_sockets: bool) -> float | None:
    """How often an idle connection's paramiko thread wakes (None: paramiko's 0.1 s).  Only where gevent
    patched sockets (CLI, status, rollout), where a close wakes the reader at once: a real thread asleep
    on a closed descriptor could read a newer socket given its number.  Keepalives (``keep_alive``
    seconds) keep their interval."""
    if not gevent_sockets:
        return None
    return float(min(IDLE_WAKEUP_SECONDS, keep_alive)) if keep_alive else IDLE_WAKEUP_SECONDS
