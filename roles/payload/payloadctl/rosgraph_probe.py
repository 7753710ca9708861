"""The ROS 1 graph probe: is the graph what a healthy release publishes?

A standalone script (Python 3 standard library only): payloadctl runs it
inside the project's roscore container, `docker exec -i <roscore> python3 -
'<expected as JSON>'` with this file on stdin, so it reads the graph from
inside the project's network whatever the network mode.

    expected: {"nodes": ["/talker"], "topics": {"/chatter": 2.0},
               "services": ["/add_two_ints"], "within": 30, "master": null}

From the master (ROS Master API, XML-RPC): getSystemState's publishers and
services; each node must be registered and answer getPid on its own XML-RPC
server; each service must be registered and answer a TCPROS probe header;
each topic's rate is measured by subscribing to every publisher itself
(requestTopic on the publisher, a TCPROS header with md5sum and type "*",
as rostopic hz does with AnyMsg) and counting message frames for a short
window.  It tries again until ``within`` seconds have passed, then prints
one JSON line: {"ok", "problems", "rates", "nodes"}; a problem is one line
naming what is wrong, e.g. "/chatter: 0.0 Hz, 2 Hz required".
"""

import difflib
import json
import os
import socket
import struct
import sys
import threading
import time
import xmlrpc.client

CALLER = "/robotfleet_health_{}".format(os.getpid())
MIN_WINDOW = 2.5  # seconds a rate is measured for, at least (two messages of a 1 Hz topic, with room)
MAX_WINDOW = 30.0  # and at most (a very low required rate)
TIMEOUT = 5.0  # seconds for one XML-RPC call or connection
PAUSE = 1.0  # seconds between tries


def window(required):
    """Seconds to count a topic's messages: long enough for three intervals at the required rate."""
    return min(MAX_WINDOW, max(MIN_WINDOW, 3.0 / required))


def rate_of(times, seconds):
    """Hz from the arrival times of a topic's messages in a window of ``seconds``."""
    times = sorted(times)
    if len(times) >= 2 and times[-1] > times[0]:
        return (len(times) - 1) / (times[-1] - times[0])
    return len(times) / seconds


def hz(value):
    return "{:g} Hz".format(value)


def encode_header(fields):
    """A TCPROS connection header: a length, then each key=value with its length."""
    body = b"".join(struct.pack("<I", len(f)) + f for f in ("{}={}".format(k, v).encode() for k, v in fields.items()))
    return struct.pack("<I", len(body)) + body


def decode_header(body):
    fields, at = {}, 0
    while at + 4 <= len(body):
        (size,) = struct.unpack("<I", body[at : at + 4])
        key, _, value = body[at + 4 : at + 4 + size].decode("utf-8", "replace").partition("=")
        fields[key] = value
        at += 4 + size
    return fields


def read_exactly(sock, size):
    data = b""
    while len(data) < size:
        chunk = sock.recv(size - len(data))
        if not chunk:
            raise EOFError("connection closed")
        data += chunk
    return data


def read_block(sock):
    (size,) = struct.unpack("<I", read_exactly(sock, 4))
    return read_exactly(sock, size)


def call(proxy, method, *args):
    """An XML-RPC call of the ROS APIs: its value, or ValueError with the status message."""
    code, message, value = getattr(proxy, method)(CALLER, *args)
    if code != 1:
        raise ValueError(message)
    return value


def closest(name, known, form=" (did you mean {}?)"):
    close = difflib.get_close_matches(name, sorted(known), n=1, cutoff=0.6)
    return form.format(close[0]) if close else ""


def count_messages(uri, topic, seconds, times):
    """Subscribe to ``topic`` at the publisher ``uri`` and note each message's arrival until ``seconds`` pass."""
    _, host, port = call(xmlrpc.client.ServerProxy(uri), "requestTopic", topic, [["TCPROS"]])
    with socket.create_connection((host, port), timeout=TIMEOUT) as sock:
        header = {"callerid": CALLER, "topic": topic, "md5sum": "*", "type": "*", "tcp_nodelay": "1"}
        sock.sendall(encode_header(header))
        reply = decode_header(read_block(sock))
        if "error" in reply:
            raise ValueError(reply["error"])
        if reply.get("latching") == "1":
            read_block(sock)  # the last message, resent to every new subscriber: not one published now
        end = time.time() + seconds
        while time.time() < end:
            sock.settimeout(max(0.01, end - time.time()))
            try:
                read_block(sock)
            except socket.timeout:
                break
            times.append(time.time())


def rates(master_uri, publishers, topics):
    """topic -> (Hz, why not measured or ""), every publisher of every topic counted at once
    (each thread its own XML-RPC proxy: one is not safe to share)."""
    times = {topic: [] for topic in topics}
    errors = {topic: [] for topic in topics}

    def one(topic, node):
        try:
            uri = call(xmlrpc.client.ServerProxy(master_uri), "lookupNode", node)
            count_messages(uri, topic, window(topics[topic]), times[topic])
        except Exception as error:  # whatever stops the count is why the topic has no rate
            errors[topic].append("{}: {}".format(node, error))

    threads = [
        threading.Thread(target=one, args=(topic, node), daemon=True)
        for topic in topics
        for node in publishers.get(topic, ())
    ]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(max(window(r) for r in topics.values()) + 4 * TIMEOUT)
    return {t: (rate_of(times[t], window(topics[t])), "; ".join(errors[t]) if not times[t] else "") for t in topics}


def node_answers(master, node):
    try:
        call(xmlrpc.client.ServerProxy(call(master, "lookupNode", node)), "getPid")
        return ""
    except (OSError, ValueError, xmlrpc.client.Error) as error:
        return str(error) or type(error).__name__


def service_answers(master, service):
    """ "" when the service's server takes a TCPROS probe (as rosservice info does), else why not."""
    try:
        host, _, port = call(master, "lookupService", service).partition("://")[2].partition(":")
        with socket.create_connection((host, int(port.strip("/"))), timeout=TIMEOUT) as sock:
            sock.sendall(encode_header({"probe": "1", "md5sum": "*", "callerid": CALLER, "service": service}))
            reply = decode_header(read_block(sock))
        return reply.get("error", "")
    except (OSError, EOFError, ValueError, xmlrpc.client.Error) as error:
        return str(error) or type(error).__name__


def look(master_uri, expected):
    """One look at the graph: (problems, {topic: Hz}, [nodes up])."""
    master = xmlrpc.client.ServerProxy(master_uri)
    try:
        published, subscribed, served = call(master, "getSystemState")
    except (OSError, ValueError, xmlrpc.client.Error) as error:
        return ["the ROS master at {} does not answer: {}".format(master_uri, error)], {}, []
    publishers = {topic: nodes for topic, nodes in published}
    services = {name: nodes for name, nodes in served}
    up = sorted({node for _name, nodes in published + subscribed + served for node in nodes})
    problems = []
    for node in expected.get("nodes") or ():
        if node not in up:
            problems.append("{}: node not up{}".format(node, closest(node, up)))
        else:
            why = node_answers(master, node)
            if why:
                problems.append("{}: node registered but not answering ({})".format(node, why))
    for service in expected.get("services") or ():
        if service not in services:
            problems.append("{}: service not offered{}".format(service, closest(service, services)))
        else:
            why = service_answers(master, service)
            if why:
                problems.append("{}: service does not answer ({})".format(service, why))
    topics = expected.get("topics") or {}
    measured = rates(master_uri, publishers, topics) if topics else {}
    for topic, required in sorted(topics.items()):
        rate, why = measured[topic]
        if rate < required:
            if topic not in publishers:
                why = "no node publishes it" + closest(topic, publishers, "; did you mean {}?")
            problems.append(
                "{}: {:.1f} Hz, {} required{}".format(topic, rate, hz(required), " ({})".format(why) if why else "")
            )
    return problems, {topic: round(rate, 2) for topic, (rate, _) in measured.items()}, up


def probe(expected):
    master_uri = expected.get("master") or os.environ.get("ROS_MASTER_URI") or "http://localhost:11311"
    deadline = time.time() + float(expected.get("within") or 0)
    while True:
        problems, measured, up = look(master_uri, expected)
        if not problems or time.time() + PAUSE >= deadline:
            return {"ok": not problems, "problems": problems, "rates": measured, "nodes": up}
        time.sleep(PAUSE)


def main(argv):
    socket.setdefaulttimeout(TIMEOUT)  # every XML-RPC call: a node that hangs is not up
    print(json.dumps(probe(json.loads(argv[1])), sort_keys=True), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
