"""The ROS graph check, run by the roscore container's python3 (`docker
exec -i CONTAINER python3 - WANTED_JSON`, this file on stdin; stdlib only,
Python 3.8+): the master's getSystemState for nodes, topics and services,
each node asked for its pid, each topic's rate counted on a TCPROS
subscription to its publishers, each service's header asked (a probe).
Until WANTED's `wait` seconds pass it looks again; then it prints one line
per problem (`/chatter: 0.0 Hz, 2 Hz required`) and exits 1; 0 when healthy.
Imports nothing of payloadctl: it runs alone in the container."""

import json
import os
import socket
import struct
import sys
import threading
import time
import xmlrpc.client

CALLER = "/robotfleet_health"
MASTER = os.environ.get("ROS_MASTER_URI") or "http://localhost:11311"


def proxy(uri):
    return xmlrpc.client.ServerProxy(uri)


def header(fields):
    body = b"".join(struct.pack("<I", len(f)) + f for f in (("%s=%s" % kv).encode() for kv in fields.items()))
    return struct.pack("<I", len(body)) + body


def read_exactly(sock, size):
    data = b""
    while len(data) < size:
        chunk = sock.recv(size - len(data))
        if not chunk:
            raise EOFError("connection closed")
        data += chunk
    return data


def read_header(sock):
    body = read_exactly(sock, struct.unpack("<I", read_exactly(sock, 4))[0])
    fields, at = {}, 0
    while at < len(body):
        size = struct.unpack("<I", body[at : at + 4])[0]
        key, _, value = body[at + 4 : at + 4 + size].decode("utf-8", "replace").partition("=")
        fields[key], at = value, at + 4 + size
    return fields


def uri_of(node):
    code, _, uri = proxy(MASTER).lookupNode(CALLER, node)
    return uri if code == 1 else None


def messages(topic, publisher, window, times):
    """Append the arrival time of each message ``publisher`` sends on ``topic`` for ``window`` seconds."""
    uri = uri_of(publisher)
    code, _, protocol = proxy(uri).requestTopic(CALLER, topic, [["TCPROS"]]) if uri else (0, "", [])
    if code != 1 or not protocol or protocol[0] != "TCPROS":
        return
    end = time.time() + window
    with socket.create_connection((protocol[1], protocol[2]), timeout=window) as sock:
        sock.sendall(header({"callerid": CALLER, "topic": topic, "md5sum": "*", "type": "*", "tcp_nodelay": "1"}))
        if "error" in read_header(sock):
            return
        while time.time() < end:
            sock.settimeout(max(0.05, end - time.time()))
            try:
                read_exactly(sock, struct.unpack("<I", read_exactly(sock, 4))[0])
            except (socket.timeout, EOFError):
                return
            times.append(time.time())


def rate(topic, publishers, window):
    """Messages per second on ``topic`` (as `rostopic hz`: over the intervals between messages)."""
    times = []
    threads = [threading.Thread(target=safe(messages), args=(topic, p, window, times)) for p in publishers]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(window + 5)
    times = sorted(times)
    return (len(times) - 1) / (times[-1] - times[0]) if len(times) > 1 and times[-1] > times[0] else 0.0


def safe(function):
    def run(*args):
        try:
            function(*args)
        except (OSError, EOFError, xmlrpc.client.Error, struct.error):
            pass

    return run


def answers(node):
    uri = uri_of(node)
    try:
        return bool(uri) and proxy(uri).getPid(CALLER)[0] == 1
    except (OSError, xmlrpc.client.Error):
        return False


def service_answers(service):
    code, _, uri = proxy(MASTER).lookupService(CALLER, service)
    if code != 1 or not uri.startswith("rosrpc://"):
        return False
    host, _, port = uri[len("rosrpc://") :].rstrip("/").rpartition(":")
    try:
        with socket.create_connection((host, int(port)), timeout=5) as sock:
            sock.sendall(header({"callerid": CALLER, "service": service, "md5sum": "*", "probe": "1"}))
            return "error" not in read_header(sock)
    except (OSError, EOFError, ValueError, struct.error):
        return False


def problems(wanted):
    """One line per way the graph is not what ``wanted`` declares ([]: healthy)."""
    code, _, state = proxy(MASTER).getSystemState(CALLER)
    if code != 1:
        return ["the master at {} did not answer getSystemState".format(MASTER)]
    publishers, _, services = ({name: nodes for name, nodes in kind} for kind in state)
    up = {node for kind in state for _, nodes in kind for node in nodes}
    found = []
    for node in wanted["nodes"]:
        if node not in up:
            found.append("{}: node not in the graph".format(node))
        elif not answers(node):
            found.append("{}: node registered but not answering".format(node))
    for topic, required in sorted(wanted["topics"].items()):
        sources = publishers.get(topic, [])
        seen = rate(topic, sources, max(2.0, 3.0 / required)) if sources else 0.0
        if seen < required:
            why = "" if sources else " (no node publishes it)"
            found.append("{}: {:.1f} Hz, {:g} Hz required{}".format(topic, seen, required, why))
    for service in wanted["services"]:
        if service not in services:
            found.append("{}: service not in the graph".format(service))
        elif not service_answers(service):
            found.append("{}: service registered but not answering".format(service))
    return found


def main(argv):
    wanted = json.loads(argv[1])
    deadline = time.time() + float(wanted.get("wait") or 0)
    while True:
        try:
            found = problems(wanted)
        except (OSError, xmlrpc.client.Error) as error:
            found = ["the master at {} does not answer: {}".format(MASTER, error)]
        if not found or time.time() >= deadline:
            break
        time.sleep(1)
    for line in found:
        print(line)
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
