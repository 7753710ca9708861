"""Why a host could not be reached, in words: the one wording of each
cause, for every command that connects (deploys and status through
robotfleet/connect.py, enroll's own key fetch), how each begins (a refusal
or the network's), the one advice for a changed host key, and the word or
two of it the status table shows."""

from __future__ import annotations

import errno
import shlex
import socket

from paramiko import SSHException
from paramiko.ssh_exception import NoValidConnectionsError

# How each reason a host cannot be reached begins (what rollout looks for in
# pyinfra's output to tell an unreachable robot from a failed one).
REASONS = (
    "unknown host key",
    "host key CHANGED",
    "host key REVOKED",
    "host certificate refused",
    "authentication failed",
    "connection refused",
    "connection closed",
    "cannot connect",
    "cannot resolve",
    "timed out",
    "not an SSH server",
    "no SSH greeting",
    "the SSH session",
    "no route to",
    "link frozen",
)
# Of those, the ones where the host answered and it or we refused: a host key
# not trusted, a login refused.  The host failed (exit status 1); the others
# are the network's (unreachable, exit status 3).
REFUSALS = (
    "unknown host key",
    "host key CHANGED",
    "host key REVOKED",
    "host certificate refused",
    "authentication failed",
)


def unreachable(reason: str) -> bool:
    """Whether a connection failure's reason is the network's (the host may
    come back by itself), not a refusal someone has to act on."""
    return not reason.startswith(REFUSALS)


def replace_advice(inventory: str, host: str) -> str:
    """The one instruction for a changed host key, wherever it is met (a deploy, status, enroll): never trust
    the new key on first use, replace it only when it matches a fingerprint recorded for the robot."""
    return (
        f"if the robot was reinstalled, record its new fingerprint and replace it: robotfleet enroll "
        f"{shlex.quote(inventory)} --replace {shlex.quote(host)} --fingerprints FILE"
    )


# The few words of each reason the status table shows after "no:" (--json has the whole line).
SHORT = (
    ("unknown host key", "host key"),
    ("host key CHANGED", "host key"),
    ("host key REVOKED", "host key"),
    ("host certificate refused", "host key"),
    ("authentication failed", "login refused"),
    ("connection refused", "refused"),
    ("connection closed", "closed"),
    ("the SSH session", "closed"),
    ("cannot resolve", "unknown name"),
    ("timed out", "timed out"),
    ("not an SSH server", "not SSH"),
    ("no SSH greeting", "no greeting"),
    ("no route to", "no route"),
    ("cannot connect", "cannot connect"),
    ("link frozen", "frozen"),
)


def short_reason(reason: str) -> str | None:
    """A connection failure's reason in a word or two (``refused``, ``timed out``, ``host key``); None for a
    line that is not one of this module's reasons."""
    return next((word for start, word in SHORT if reason.startswith(start)), None)


def frozen(address: str, port: int, seconds: float, interval: int, count_max: int) -> str:
    """A connection that stopped answering (robotfleet/keepalive.py), ended by its keepalives."""
    return (
        f"link frozen: no answer from {address}:{port} for {seconds:.0f} s, the connection was given up "
        f"(ssh_keepalive_interval: {interval}, ssh_keepalive_count_max: {count_max})"
    )


def closed_during_command(address: str, port: int, error: BaseException | None) -> str:
    """A connection the host or the link closed while a command ran (a cut link, sshd or the host gone)."""
    why = f" ({error.strerror})" if isinstance(error, OSError) and error.strerror else ""
    return f"connection closed by {address}:{port} during a command{why}: the link dropped, or sshd or the host stopped"


def greeting_seen(transport) -> bool:
    """Whether paramiko's ``transport`` (None: none made) read the server's SSH greeting."""
    return bool(getattr(transport, "remote_version", ""))


def network_reason(
    error: Exception, address: str, port: int, timeout: float, elapsed: float | None = None, greeted: bool = True
) -> tuple[str, bool]:
    """Why reaching ``address:port`` failed, in words, and whether trying
    again may help (a host key or login failure is told by the connector).
    ``timeout``: the attempt's limit; ``elapsed``: how long it took;
    ``greeted``: whether the server's SSH greeting came (``greeting_seen``)."""
    at = f"{address}:{port}"
    timeout = f"{timeout:.0f}" if timeout >= 1 else f"{timeout:.1f}"
    elapsed = float(timeout) if elapsed is None else elapsed
    if isinstance(error, NoValidConnectionsError):  # paramiko's wrapper: worded as its sockets' own error
        inner = [e for e in error.errors.values() if isinstance(e, OSError)]
        error = next((e for e in inner if e.errno != errno.ECONNREFUSED), inner[0] if inner else error)
    if isinstance(error, ConnectionRefusedError):
        return f"connection refused by {at} (no SSH server listens on port {port})", True
    if isinstance(error, socket.gaierror):
        return f"cannot resolve {address} ({error.strerror})", False
    if isinstance(error, (socket.timeout, TimeoutError)):
        return (
            f"timed out after {timeout} s connecting to {at} (no answer: powered off, wrong address or a firewall)"
        ), True
    if isinstance(error, SSHException):
        text = str(error)
        if "Error reading SSH protocol banner" in text and isinstance(error.__context__, (EOFError, ConnectionError)):
            return (
                f"connection closed by {at} before the SSH greeting (an sshd turning connections away, "
                "e.g. MaxStartups, or a firewall)"
            ), True
        if "Indecipherable protocol version" in text or (
            "Error reading SSH protocol banner" in text and elapsed < float(timeout) - 0.5
        ):
            # paramiko waits 2 s for each line after a first one that is not SSH's
            return (
                f"not an SSH server: {at} answered, but not with an SSH greeting (another service on that "
                "port? wrong port?)"
            ), False
        # paramiko's wait for the handshake and its wait for the greeting end together; under load the
        # first may end first, and the missing greeting shows only as "No existing session"
        if "Error reading SSH protocol banner" in text or ("No existing session" in text and not greeted):
            return (
                f"no SSH greeting: {at} accepted the connection but sent nothing within {timeout} s: "
                "a link that stalls (Wi-Fi, LTE), or not an SSH server (wrong port?)"
            ), False
        if "No existing session" in text or "Unable to connect" in text:
            return f"the SSH session to {at} closed during the handshake", True
        return f"SSH error from {at}: {text}", False
    if isinstance(error, EOFError):
        return f"connection closed by {at} during the SSH handshake", True
    if isinstance(error, OSError):
        if error.errno in (errno.EHOSTUNREACH, errno.ENETUNREACH):
            return f"no route to {at} ({error.strerror})", True
        return f"cannot connect to {at} ({error.strerror or error})", True
    return f"cannot connect to {at} ({type(error).__name__}: {error})", False
