"""Real servers on 127.0.0.1 for first-contact tests (no mocks): an SSH
server (paramiko's server side) with its own host key, a TCP listener that
never speaks (or greets as another service would), a port whose
connections are never answered (a powered-off robot), and a closed port.
Each counts the connections it accepted, so a test sees whether the client
tried again."""

from __future__ import annotations

import socket
import threading
from contextlib import contextmanager

import paramiko


class _Server(paramiko.ServerInterface):
    def __init__(self, accepted_key, answer=None, global_requests=None):
        self.accepted_key = accepted_key
        self.answer = answer  # command -> (stdout bytes, exit status); default: nothing, 0
        self.global_requests = global_requests if global_requests is not None else []

    def check_global_request(self, kind, msg):
        self.global_requests.append(kind)  # e.g. a client's keepalive@lag.net
        return False

    def get_allowed_auths(self, username):
        return "publickey"

    def check_auth_publickey(self, username, key):
        if self.accepted_key is not None and key == self.accepted_key:
            return paramiko.AUTH_SUCCESSFUL
        return paramiko.AUTH_FAILED

    def check_channel_request(self, kind, chanid):
        return paramiko.OPEN_SUCCEEDED if kind == "session" else paramiko.OPEN_FAILED_ADMINISTRATIVELY_PROHIBITED

    def check_channel_exec_request(self, channel, command):
        def answer():
            out, code = self.answer(command.decode(errors="replace")) if self.answer else (b"", 0)
            if out:
                channel.sendall(out)
            channel.send_exit_status(code)
            channel.close()

        threading.Thread(target=answer, daemon=True).start()
        return True


class Listener:
    """Accepts TCP connections on 127.0.0.1; ``ssh`` decides what it says."""

    def __init__(self, host_key=None, client_key=None, hang_up=False, greeting: bytes = b"", answer=None):
        self.hang_up = hang_up  # close each connection at once (an sshd over MaxStartups)
        self.greeting = greeting  # sent on each connection, then silence (another service on the port)
        self.socket = socket.create_server(("127.0.0.1", 0))
        self.port = self.socket.getsockname()[1]
        self.host_key, self.client_key = host_key, client_key
        self.answer = answer
        self.connections = 0
        self.global_requests: list[str] = []
        self.open: list = []
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self):
        while True:
            try:
                conn, _ = self.socket.accept()
            except OSError:
                return
            self.connections += 1
            if self.hang_up:
                conn.close()
                continue
            self.open.append(conn)
            if self.greeting:
                conn.sendall(self.greeting)
            if self.host_key is not None:
                threading.Thread(target=self._ssh, args=(conn,), daemon=True).start()

    def _ssh(self, conn):
        transport = paramiko.Transport(conn)
        self.open.append(transport)
        transport.add_server_key(self.host_key)
        try:
            transport.start_server(server=_Server(self.client_key, self.answer, self.global_requests))
        except (paramiko.SSHException, EOFError, OSError):
            return

    def close(self):
        # shutdown first: close alone leaves the accept() blocked in _serve's thread listening in the kernel,
        # and under load the next test's server came to share its port (a client then met this one's host key)
        try:
            self.socket.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self.socket.close()
        for item in self.open:
            try:
                item.close()
            except OSError:
                pass


def ssh_server(client_key=None, answer=None) -> Listener:
    """An SSH server accepting ``client_key``; each command it is sent gets
    ``answer(command)`` -> (stdout, exit status), by default nothing and 0."""
    return Listener(host_key=paramiko.ECDSAKey.generate(), client_key=client_key, answer=answer)


@contextmanager
def wrong_hosts():
    """(a listener that accepts TCP but never speaks SSH, a port nothing
    listens on): the two wrong hosts an operator meets first."""
    silent = Listener()
    try:
        yield silent, closed_port()
    finally:
        silent.close()


class Unanswered:
    """A port on 127.0.0.1 whose connections are never answered: a listener
    with a backlog of one that never accepts, its queue filled, so that the
    kernel drops every further SYN and a client's connect times out, as with
    a powered-off robot or a firewall that drops."""

    def __init__(self):
        self.socket = socket.socket()
        self.socket.bind(("127.0.0.1", 0))
        self.socket.listen(0)
        self.port = self.socket.getsockname()[1]
        self.filler = socket.create_connection(("127.0.0.1", self.port), timeout=2)

    def close(self):
        self.filler.close()
        self.socket.close()


def closed_port() -> int:
    """A port nothing listens on (bound, then released)."""
    probe = socket.create_server(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    return port
