"""Idle connections in a large run (issue 29, item 4): paramiko's transport
thread wakes every 0.1 s to look for a close, a keepalive or a rekey; the
operator's connector lets a connected host sleep longer where gevent runs
the sockets (robotfleet/connect.py, idle_wakeup), and keeps what the
wake-ups were for: a keepalive (ssh_keepalive_interval) still goes out on
time, and closing the connection ends its reader at once.  A real SSH
server on 127.0.0.1 (tests/integration/sshserver.py), the operator in its
own process as the CLI runs it."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from robotfleet import hostkeys
from robotfleet.connect import idle_wakeup
from tests.fixtures import ROOT
from tests.integration import sshserver
from tests.integration.operator_side import fleet

# Connects to every host of inventories/robots.py as the CLI does (pyinfra_cli
# patches the sockets with gevent), idles, then closes; prints what each
# connection's transport did.
OPERATOR = r"""
import gc, json, sys, time
import greenlet
from pyinfra.api import Config, State
from pyinfra.context import ctx_state
from pyinfra_cli.inventory import make_inventory
def reading():
    "Whether a greenlet is still in paramiko's transport loop."
    for g in gc.get_objects():
        if isinstance(g, greenlet.greenlet) and g and not g.dead:
            frame = g.gr_frame
            while frame is not None:
                if frame.f_code.co_name == "run" and frame.f_code.co_filename.endswith("paramiko/transport.py"):
                    return True
                frame = frame.f_back
    return False
with ctx_state.use(State()):
    inventory = make_inventory("inventories/robots.py")
state = State(inventory=inventory, config=Config())
report = {}
with ctx_state.use(state):
    for host in inventory:
        host.connect(raise_exceptions=True, show_errors=False)
        transport = host.connector.client.get_transport()
        timeout = transport.sock.gettimeout()
        time.sleep(float(sys.argv[1]))
        before = reading()
        started = time.monotonic()
        host.connector.client.close()
        while reading() and time.monotonic() - started < 10:
            time.sleep(0.01)
        report[host.name] = {"timeout": timeout, "reading_before": before,
                             "reader_ended_after": round(time.monotonic() - started, 2)}
print(json.dumps(report))
"""


@pytest.mark.parametrize(
    ("keep_alive", "timeout", "keepalives"),
    [
        (None, 5.0, 0),  # a connected host sleeps 5 s between looks (keepalives every 15 s)
        (1, 1.0, 2),  # ssh_keepalive_interval 1: sent each second
    ],
)
def test_an_idle_connection_sleeps_longer_and_keeps_its_keepalives(
    tmp_path, client_key, keep_alive, timeout, keepalives
):
    server = sshserver.ssh_server(client_key)
    try:
        path = fleet(
            tmp_path,
            {"robot1": {"address": "127.0.0.1", "ssh_port": server.port}},
            ssh_keepalive_interval=keep_alive,
        )
        key = server.host_key
        (tmp_path / "known_hosts").write_text(
            f"{hostkeys.entry('127.0.0.1', server.port)} {key.get_name()} {key.get_base64()}\n"
        )
        result = subprocess.run(
            [sys.executable, "-c", OPERATOR, "2.6"],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=60,
            env={"PATH": "/usr/bin:/bin", "ROBOT_FLEET": str(path), "HOME": str(tmp_path)},
        )
        assert result.returncode == 0, result.stderr[-2000:]
        report = json.loads(result.stdout.splitlines()[-1])["robot1"]
    finally:
        server.close()
    assert report["timeout"] == timeout
    assert server.global_requests.count("keepalive@openssh.com") >= keepalives
    if not keepalives:
        assert "keepalive@openssh.com" not in server.global_requests
    # A close wakes the reader: it does not sleep its 5 s out.
    assert report["reading_before"] and report["reader_ended_after"] < 1.0, report


def test_with_real_threads_paramiko_keeps_its_own():
    """A reader asleep on a closed descriptor could read a newer socket given its number."""
    assert idle_wakeup(0, gevent_sockets=False) is None and idle_wakeup(3, gevent_sockets=False) is None
    assert idle_wakeup(0, gevent_sockets=True) == 5.0 and idle_wakeup(30, gevent_sockets=True) == 5.0
