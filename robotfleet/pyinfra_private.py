"""Every private name of pyinfra (and of paramiko and python-tuf beneath it)
that robotfleet and the roles use, in one place, with where and why the
public API does not do.

Private: an underscore name, a name of pyinfra.api's modules that
``pyinfra.api`` does not export, ``pyinfra.context``, the connectors'
insides, ``pyinfra_cli``, and what State and paramiko's client keep on
their objects.  Each entry is pinned to the digest of the pyinfra source
that defines or uses it, as of pyinfra 3.10: tests/unit/test_pyinfra_private.py
fails, naming the entry, when the installed pyinfra removes a name or
changes that source.  Read what changed, make the code that uses it right,
then update the digest here.
"""

from __future__ import annotations

import hashlib
import importlib
import inspect
from dataclasses import dataclass


@dataclass(frozen=True)
class Private:
    names: tuple[str, ...]  # "module:attribute.attribute", each must exist
    source: str  # the pinned source: what defines or uses the names
    digest: str  # sha256 of that source, first 16 hex digits
    used_in: str
    why: str


USED = (
    Private(
        (
            "pyinfra.connectors.ssh:SSHConnector.connect",
            "pyinfra.connectors.ssh_util:_patch_paramiko_sk_key_support",
            "pyinfra.connectors.ssh:SSHConnector._retry_paramiko_agent_keys",
        ),
        "pyinfra.connectors.ssh:SSHConnector.connect",
        "32da021d77c0af3e",
        "robotfleet/connect.py",
        "FleetConnector.connect replaces pyinfra's to tell each failure in one line and retry only what may "
        "pass; it repeats its steps: FIDO key support first, the agent-key retry after a failed login",
    ),
    Private(
        ("pyinfra.connectors.ssh:SSHConnector.make_paramiko_kwargs",),
        "pyinfra.connectors.ssh:SSHConnector.make_paramiko_kwargs",
        "2adb0b9401ccf9f2",
        "robotfleet/connect.py",
        "the arguments pyinfra gives paramiko, to which the connector adds its connect, banner and auth timeouts",
    ),
    Private(
        (
            "pyinfra.connectors.ssh:ConnectorData",
            "pyinfra.connectors.ssh:connector_data_meta",
            "pyinfra.connectors.ssh:DataMeta",
        ),
        "pyinfra.connectors.ssh:ConnectorData",
        "28160830436a3e35",
        "robotfleet/connect.py",
        "the SSH connector's data (ssh_connect_retries and its delays, ssh_key, ...), extended by ssh_connect_timeout",
    ),
    Private(
        ("pyinfra.connectors.sshuserclient.client:SSHClient.parse_config",),
        "pyinfra.connectors.sshuserclient.client:SSHClient.parse_config",
        "bdce1ea5a063130a",
        "robotfleet/connect.py",
        "its result's fourth item is the host-key policy: swapped for one that names the file and the enroll "
        "command (strict), or writes a key once (accept-new); its sixth, ssh_config's ServerAliveInterval, "
        "is zeroed: the fleet's keepalives (robotfleet/keepalive.py) replace pyinfra's send-only one",
    ),
    Private(
        ("paramiko.packet:Packetizer.set_keepalive", "paramiko.transport:Transport.global_request"),
        "paramiko.packet:Packetizer._check_keepalive",
        "3b0c2f57931ff10c",
        "robotfleet/keepalive.py, robotfleet/connect.py",
        "paramiko's keepalive callback is the one hook in its transport thread that runs when a read finds "
        "nothing after an interval without a write: the watch counts unanswered keepalives there and ends "
        "the transport by raising (transport.packetizer); the error the transport saved "
        "(transport.saved_exception) says why a command's connection ended",
    ),
    Private(
        ("pyinfra.connectors.util:CommandOutput", "pyinfra.connectors.util:OutputLine"),
        "pyinfra.connectors.ssh:SSHConnector.run_shell_command",
        "6e742d04535439d4",
        "robotfleet/connect.py",
        "a command whose connection ended under it gets the reason as a last stderr line of its output, "
        "which pyinfra prints with the host's name and status reads",
    ),
    Private(
        ("paramiko.transport:Transport._active_check_timeout",),
        "paramiko.packet:Packetizer.read_all",
        "d6eccad5d1d31e06",
        "robotfleet/connect.py",
        "the transport's socket timeout (0.1 s, set from _active_check_timeout) is how often its reading "
        "thread wakes to look for a close, a keepalive or a rekey; a connected one is given a longer one",
    ),
    Private(
        ("pyinfra.connectors.sshuserclient.client:SSHClient.connect",),
        "pyinfra.connectors.sshuserclient.client:SSHClient.connect",
        "bd3ef101b4c6a71b",
        "robotfleet/connect.py",
        "it keeps the ssh_config it applied as client._ssh_config: the port and user a failure line names",
    ),
    Private(
        (
            "pyinfra.connectors.sshuserclient.client:HOST_KEYS_LOCK",
            "pyinfra.connectors.sshuserclient.client:AcceptNewPolicy",
        ),
        "pyinfra.connectors.sshuserclient.client:AcceptNewPolicy",
        "2a063ae75c978d38",
        "robotfleet/hostkey_policy.py",
        "accept-new appends to known_hosts under pyinfra's own lock, as pyinfra's policy does",
    ),
    Private(
        ("paramiko.client:SSHClient.load_host_keys",),
        "paramiko.client:SSHClient.load_host_keys",
        "7fae5f7a194e4436",
        "robotfleet/hostkey_policy.py",
        "paramiko's (through pyinfra's client): the loaded keys (client._host_keys) and their file "
        "(client._host_keys_filename), where accept-new adds a key",
    ),
    Private(
        ("paramiko.client:SSHClient.set_missing_host_key_policy",),
        "paramiko.client:SSHClient.set_missing_host_key_policy",
        "8fb5d9f7d649bbd7",
        "robotfleet/hostkey_policy.py",
        "the policy it stores (client._policy) tells the connector the fleet's known_hosts, which it reads "
        "itself (paramiko stops at an @cert-authority line)",
    ),
    Private(
        (
            "tuf.ngclient.updater:Updater.__init__",
            "tuf.ngclient._internal.trusted_metadata_set:TrustedMetadataSet.__init__",
        ),
        "tuf.ngclient._internal.trusted_metadata_set:TrustedMetadataSet.__init__",
        "b6c0de0257e7cd4a",
        "robotfleet/pull/robot/tufprivate.py",
        "expiry is checked against updater._trusted_set.reference_time (the clock when it was made): set to "
        "max(clock, last trusted time) for robots without an RTC",
    ),
    Private(
        ("pyinfra.api.arguments:CONNECTOR_ARGUMENT_KEYS", "pyinfra.api.arguments:ConnectorArguments"),
        "pyinfra.api.arguments:ConnectorArguments",
        "c0b7f09d979abf6c",
        "robotfleet/host/operations.py",
        "which of an operation's keyword arguments go to host.run_shell_command (_sudo, _stdin, ...)",
    ),
    Private(
        ("pyinfra.api.util:format_text",),
        "pyinfra.api.util:format_text",
        "99b77a99f314cce9",
        "robotfleet/host/operations.py",
        "--diff output styled as pyinfra styles its own",
    ),
    Private(
        ("pyinfra.api.util:print_host_combined_output",),
        "pyinfra.api.util:print_host_combined_output",
        "0f8f6b46d94048cd",
        "robotfleet/host/operations.py",
        "a failed command's output printed as pyinfra prints it",
    ),
    Private(
        ("pyinfra.context:ctx_host", "pyinfra.context:ctx_state"),
        "pyinfra.context",
        "33bb90a61c5910ca",
        "robotfleet/host/operations.py, robotfleet/selection.py, robotfleet/commands/status_collect.py",
        "the current host (a failure recorded while planning) and a State for inventories built outside "
        "the CLI (status, rollout, enroll)",
    ),
    Private(
        (
            "pyinfra.api.state:State.is_executing",
            "pyinfra.api.state:State.should_check_for_changes",
            "pyinfra.api.state:State.print_output",
            "pyinfra.api.state:State.current_deploy_filename",
            "pyinfra.api.state:State.current_op_file_number",
        ),
        "pyinfra.api.state:State",
        "8c6b6d12b1c7c768",
        "robotfleet/host/operations.py, robotfleet/commands/status_collect.py, robotfleet/pyinfra_patches.py, "
        "roles/payload/release.py",
        "planning or executing (operations compare with the snapshot while planning; the payload writes its "
        "release for a window's switch only while planning), whether to print "
        "output, failed_hosts and limit_hosts (a State's attributes set in __init__), and where the "
        "deploy file is (operation order)",
    ),
    Private(
        ("pyinfra_cli.inventory:make_inventory",),
        "pyinfra_cli.inventory:make_inventory",
        "90cfda6b5a4363bb",
        "robotfleet/selection.py, robotfleet/commands/status_collect.py",
        "an inventory file read exactly as the CLI reads it, for status, rollout and enroll",
    ),
    Private(
        ("pyinfra_cli.main:main",),
        "pyinfra_cli.main:main",
        "cbbeb6d255bf3a6c",
        "robotfleet/commands/rollout.py",
        "each wave runs pyinfra's CLI with this interpreter (python -c), whatever pyinfra is first on PATH",
    ),
    Private(
        ("pyinfra_cli.util:parse_cli_arg",),
        "pyinfra_cli.util:parse_cli_arg",
        "fb0d4e83f8ca57c3",
        "robotfleet/commands/rollout_judge.py",
        "a rollout reads its --data values as the CLI it passes them to does (true, 3, JSON text), so "
        "what each wave waits for is what the deploy sees",
    ),
    Private(
        ("pyinfra_cli.cli:cli",),
        "pyinfra_cli.cli:cli.callback",
        "2b99e4aeb78cadcf",
        "robotfleet/inventory.py",
        "an inventory file reads the CLI's --limit and --exclude (click's params 'limit', 'exclude') to "
        "refuse a pattern that matches no host",
    ),
    Private(
        (
            "pyinfra.api.operation:get_operation_order_from_stack",
            "pyinfra.api.util:PYINFRA_INSTALL_DIR",
            "pyinfra:is_cli",
        ),
        "pyinfra.api.operation:get_operation_order_from_stack",
        "f4807f61585570e0",
        "robotfleet/pyinfra_patches.py",
        "replaced by a copy that reads no source file (a third of a converged rerun's CPU); the copy uses "
        "the install directory and CLI flag as pyinfra's does",
    ),
    Private(
        ("pyinfra.api.connectors:get_all_connectors", "pyinfra.api.connectors:entry_points"),
        "pyinfra.api.connectors:get_all_connectors",
        "7d05cb4b81d92078",
        "robotfleet/pyinfra_patches.py",
        "the entry_points it calls (importlib's, once per host named @connector/...) replaced by one that "
        "reads them once",
    ),
    Private(
        (
            "pyinfra.api.arguments:pop_global_arguments",
            "pyinfra.api.arguments:all_argument_meta",
            "pyinfra.api.arguments:ctx_config",
            "pyinfra.api.arguments:raise_if_bad_type",
            "pyinfra.api.operation:pop_global_arguments",
            "pyinfra.api.deploy:pop_global_arguments",
            "pyinfra.api.facts:pop_global_arguments",
        ),
        "pyinfra.api.arguments:pop_global_arguments",
        "a12a311539ff5068",
        "robotfleet/pyinfra_patches.py",
        "replaced where it is imported by name and called (operation, deploy, facts) by a copy that reads "
        "the host's data layers (HostData.datas) once for all the arguments, with the same argument "
        "metadata, config and type check",
    ),
    Private(
        ("pyinfra.api.operation:_wrap_operation", "pyinfra.api.operation:signature"),
        "pyinfra.api.operation:_wrap_operation",
        "8195e098a9c6a0b3",
        "robotfleet/pyinfra_patches.py",
        "the inspect.signature it calls for every operation of every host (signature(func).bind) replaced "
        "where it is imported by one that makes each function's Signature once",
    ),
    Private(
        ("pyinfra.api.host:HostData.__getattr__",),
        "pyinfra.api.host:HostData.__getattr__",
        "87152f64f2a65e53",
        "robotfleet/pyinfra_patches.py",
        "the copy of pop_global_arguments looks a key up in the host's data layers (HostData.datas) as it does",
    ),
)


def resolve(path: str):
    """``module:attribute.attribute`` (or a module) to the object."""
    module, _, attributes = path.partition(":")
    found = importlib.import_module(module)
    for name in filter(None, attributes.split(".")):
        found = getattr(found, name)
    return found


def digest(thing) -> str:
    """The first 16 hex digits of the sha256 of ``thing``'s source ("" without one)."""
    try:
        source = inspect.getsource(thing)
    except (OSError, TypeError):
        return ""
    return hashlib.sha256(source.encode()).hexdigest()[:16]


def pinned(path: str) -> str:
    """The digest recorded for the source at ``path``."""
    return next(entry.digest for entry in USED if entry.source == path)
