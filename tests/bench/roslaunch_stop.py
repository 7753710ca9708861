"""Benchmark: a roslaunch of several nodes stopped as the payload stops it
(issue 52 item 4).  Prints figures; asserts nothing.

    python3 -m tests.bench.roslaunch_stop [--nodes 6] [--rounds 3] [--signals SIGINT,SIGTERM]

One container of the lab's ROS 1 image (tests/lab/ros_images.py: Debian
bookworm's roslaunch 1.16) runs a launch file of ``--nodes`` nodes
(rostopic pub and echo, half each, on their own topics) beside the master
roslaunch starts itself.  Once every node is registered, the container is
stopped as `docker compose down` stops a payload service: its stop signal
(the one the ROS presets write, `stop_signal` from roles/payload/presets.py;
SIGTERM is Docker's default, for comparison), the grace period the role
writes (payload_stop_grace_period, Docker's 10 s when unset), then removed.
The figure: from the stop to the container gone (Docker's API, so no CLI
start is in it), the stop alone, and its exit code (137: killed when the
grace ran out).  Needs only this machine's Docker engine, no lab.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time

from tests.bench import hygiene

LAUNCH_PATH = "/tmp/nodes.launch"


def launch_file(nodes: int) -> str:
    """A launch file of ``nodes`` rostopic nodes: publishers on /t0, /t1, ..., an echo of each."""
    lines = ["<launch>"]
    for index in range(nodes):
        topic = f"/t{index // 2}"
        if index % 2 == 0:
            args = f"pub -r 10 {topic} std_msgs/String 'data: n{index}'"
            lines.append(f'  <node name="pub{index}" pkg="rostopic" type="rostopic" args="{args}"/>')
        else:
            lines.append(f'  <node name="echo{index}" pkg="rostopic" type="rostopic" args="echo {topic}"/>')
    return "\n".join(lines + ["</launch>", ""])


def role_stop() -> tuple[str, int]:
    """The stop signal the ros1 preset writes and the grace period Docker applies (the role's, else 10 s)."""
    from roles.payload import presets
    from roles.payload.settings import DEFAULTS

    keys = presets.preset({**DEFAULTS, "ros_preset": "ros1", "ros_master_uri": "http://localhost:11311"}, "127.0.0.1")
    grace = DEFAULTS.get("payload_stop_grace_period")
    return keys["keys"]["stop_signal"], 10 if grace is None else int(grace)


def registered(container, nodes: int) -> bool:
    code, out = container.exec_run(["rosnode", "list"])
    return code == 0 and len([n for n in out.decode().split() if n[1:4] in ("pub", "ech")]) >= nodes


def one_stop(dc, image: str, nodes: int, signal: str, grace: int) -> tuple[float, float, int]:
    """(stop to gone, stop alone, exit code) of one launch."""
    script = f"cat > {LAUNCH_PATH} <<'EOF'\n{launch_file(nodes)}EOF\nexec roslaunch {LAUNCH_PATH}"
    container = dc.containers.run(
        image,
        ["/bin/bash", "-c", script],
        detach=True,
        stop_signal=signal,
        network_mode="none",
        environment={"ROS_MASTER_URI": "http://localhost:11311", "ROS_HOSTNAME": "localhost"},
        name=f"bench-roslaunch-stop-{os.getpid()}",
    )
    try:
        deadline = time.monotonic() + 60
        while not registered(container, nodes):
            if time.monotonic() > deadline:
                raise SystemExit(f"roslaunch_stop: the {nodes} nodes did not register within 60 s")
            time.sleep(0.5)
        time.sleep(1)  # the nodes past their start
        start = time.monotonic()
        container.stop(timeout=grace)
        stopped = time.monotonic()
        code = container.wait()["StatusCode"]
        container.remove()
        gone = time.monotonic()
        return gone - start, stopped - start, code
    except BaseException:
        container.remove(force=True)
        raise


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--nodes", type=int, default=6)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--signals", default="", help="comma-separated; default: the role's, then SIGTERM")
    args = parser.parse_args(argv)
    from tests.lab import ros_images
    from tests.lab.engine import client

    dc = client()
    image = ros_images.build(dc)
    signal, grace = role_stop()
    signals = [s for s in args.signals.split(",") if s] or list(dict.fromkeys([signal, "SIGTERM"]))
    print(f"roslaunch of {args.nodes} nodes (+ its master) in {image}; the role stops with {signal}, grace {grace} s")
    print(f"machine: {platform.node()} {platform.machine()}, {os.cpu_count()} cores")
    for name in signals:
        figure, stops, codes = hygiene.Figure(), [], []
        for index in range(args.rounds):
            load, idle = hygiene.wait(f"roslaunch stop {name}", first=index == 0)
            total, stop, code = one_stop(dc, image, args.nodes, name, grace)
            figure.add(total, load, idle)
            stops.append(stop)
            codes.append(code)
        print(
            f"{name:8} stop to container gone: median {figure.median:.2f} s "
            f"({min(figure.samples):.2f}-{max(figure.samples):.2f}), the stop alone {statistics.median(stops):.2f} s, "
            f"exit codes {codes}, load {figure.loads}{'' if figure.idle else ' (LOADED)'}"
        )
    print(f"taken {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
