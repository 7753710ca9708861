"""A bad link on 127.0.0.1: a TCP proxy to a port whose faults a test sets
while connections run through it (docs: tests/lab/README.md, "Bad links").

- ``delay``: seconds each way (a round trip costs twice that), set any time;
  each chunk is delivered that long after it was read, in order.
- ``cut()``: both sides of every open connection closed at once (a dropped
  link); later connections pass.
- ``freeze()``: every open connection, and each new one until ``thaw()``,
  is kept open and forwards nothing more, either way (a cell hand-over, a
  stalled tunnel: what TCP itself never reports).  A frozen connection
  stays frozen; ``thaw()`` lets new ones pass.

Threads, no asyncio: a pytest process or a benchmark starts it beside
what it runs.  ``sent`` and ``received`` count the bytes to the target and
back; ``connections`` the connections accepted.  ``through`` points the
lab's inventory (inventories/lab.py) at links for some of its hosts."""

from __future__ import annotations

import json
import queue
import socket
import threading
import time

CHUNK = 65536


def through(state: dict, links: dict) -> dict:
    """The environment that has inventories/lab.py reach each host of
    ``links`` (name -> Link to that host's SSH port) through its link: the
    ports, and a copy of the lab's known_hosts with each host's keys also
    under its link's port (written beside it)."""
    ports = {h["name"]: h["port"] for h in state["hosts"]}
    lines = open(state["known_hosts"]).read().splitlines()
    for name, link in links.items():
        at = f"[127.0.0.1]:{ports[name]} "
        lines += [f"[127.0.0.1]:{link.port} " + line[len(at) :] for line in lines if line.startswith(at)]
    path = f"{state['known_hosts']}.links"
    with open(path, "w") as out:
        out.write("\n".join(lines) + "\n")
    return {
        "ROBOT_LAB_VIA": json.dumps({name: link.port for name, link in links.items()}),
        "ROBOT_LAB_KNOWN_HOSTS": path,
    }


class Link:
    def __init__(self, target_port: int, target_host: str = "127.0.0.1", delay: float = 0.0):
        self.target = (target_host, target_port)
        self.delay = delay
        self.frozen = False
        self.connections = 0
        self.sent = self.received = 0
        self._open: list[_Connection] = []
        self._lock = threading.Lock()
        self._server = socket.create_server(("127.0.0.1", 0))
        self.port = self._server.getsockname()[1]
        threading.Thread(target=self._accept, name=f"link:{self.port}", daemon=True).start()

    def cut(self) -> None:
        with self._lock:
            cut, self._open = self._open, []
        for connection in cut:
            connection.close()

    def freeze(self) -> None:
        with self._lock:
            self.frozen = True
            for connection in self._open:
                connection.frozen = True

    def thaw(self) -> None:
        self.frozen = False

    def close(self) -> None:
        try:
            self._server.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self._server.close()
        self.cut()

    def __enter__(self) -> Link:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _accept(self) -> None:
        while True:
            try:
                client, _ = self._server.accept()
            except OSError:
                return
            self.connections += 1
            try:
                target = None if self.frozen else socket.create_connection(self.target, timeout=10)
            except OSError:
                client.close()
                continue
            connection = _Connection(self, client, target)
            with self._lock:
                self._open.append(connection)
                connection.frozen = self.frozen

    def _count(self, upstream: bool, size: int) -> None:
        with self._lock:
            if upstream:
                self.sent += size
            else:
                self.received += size

    def _ended(self, connection: _Connection) -> None:
        with self._lock:
            if connection in self._open:
                self._open.remove(connection)


class _Connection:
    """One proxied connection: each way a reader (stamps each chunk with its
    due time) and a writer (delivers it then); None ends the way."""

    def __init__(self, link: Link, client: socket.socket, target: socket.socket | None):
        self.link, self.client, self.target = link, client, target
        self.frozen = False
        self.closed = threading.Event()
        self._ways = 2
        if target is None:  # accepted while frozen: held open, never connected
            return
        target.settimeout(None)
        for source, sink, upstream in ((client, target, True), (target, client, False)):
            pending: queue.Queue = queue.Queue()
            threading.Thread(target=self._read, args=(source, pending, upstream), daemon=True).start()
            threading.Thread(target=self._write, args=(sink, pending), daemon=True).start()

    def _read(self, source: socket.socket, pending: queue.Queue, upstream: bool) -> None:
        while True:
            try:
                data = source.recv(CHUNK)
            except OSError:
                data = b""
            if self.frozen:
                self.closed.wait()  # nothing more is read, nothing delivered, until the end
                return
            if data:
                self.link._count(upstream, len(data))
            pending.put((time.monotonic() + self.link.delay, data or None))
            if not data:
                return

    def _write(self, sink: socket.socket, pending: queue.Queue) -> None:
        while True:
            due, data = pending.get()
            wait = due - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            if self.frozen:
                self.closed.wait()
                return
            if data is None:
                break
            try:
                sink.sendall(data)
            except OSError:
                break
        try:
            sink.shutdown(socket.SHUT_WR)
        except OSError:
            pass
        with self.link._lock:
            self._ways -= 1
            ended = self._ways == 0
        if ended:
            self.close()

    def close(self) -> None:
        self.closed.set()
        for sock in (self.client, self.target):
            if sock is None:
                continue
            try:
                sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            sock.close()
        self.link._ended(self)
