"""What one more host costs the operator's machine in pyinfra's gevent pool:
open file descriptors and resident memory of the pyinfra process, sampled
while N SSH connections are open at once.

    python3 -m tests.bench.pool [--prefix bench] [--hosts 1 10 30]

N inventory names all point at the first robot of a running lab (one sshd),
so N connections cost the laptop what N robots would without starting N
containers.  The robot's sshd sees N connections at once: more than its
MaxStartups (default 10:30:100) unauthenticated ones are dropped at random,
which is what ssh_connect_retries is for.  Prints the figures.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from tests.fixtures import start_pyinfra

ROOT = Path(__file__).resolve().parents[2]


def inventory(state: dict, n: int) -> str:
    robot = state["hosts"][0]
    data = {
        "ssh_hostname": "127.0.0.1",
        "ssh_port": robot["port"],
        "ssh_user": state["ssh_user"],
        "ssh_key": state["ssh_key"],
        "ssh_known_hosts_file": state["known_hosts"],
        "ssh_strict_host_key_checking": "yes",
        "ssh_allow_agent": False,
        "ssh_look_for_keys": False,
        "ssh_connect_retries": 5,
        "ssh_connect_retry_min_delay": 0.2,
        "ssh_connect_retry_max_delay": 1,
    }
    return f"hosts = [(f'alias{{i}}', {data!r}) for i in range({n})]\n"


def sample(pid: int) -> tuple[int, int]:
    try:
        fds = len(os.listdir(f"/proc/{pid}/fd"))
        rss = next(int(line.split()[1]) for line in open(f"/proc/{pid}/status") if line.startswith("VmRSS:"))
        return fds, rss
    except (OSError, StopIteration):
        return 0, 0


def measure(state: dict, n: int, hold: float) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        inv = Path(tmp) / "aliases.py"
        inv.write_text(inventory(state, n))
        started = time.monotonic()
        proc = start_pyinfra(
            "-y",
            str(inv),
            "exec",
            "--",
            f"sleep {hold}",
            cwd=tmp,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
            env=dict(os.environ, PYINFRA_PROGRESS="off"),
        )
        peak_fds = peak_rss = 0
        while proc.poll() is None:
            fds, rss = sample(proc.pid)
            peak_fds, peak_rss = max(peak_fds, fds), max(peak_rss, rss)
            time.sleep(0.05)
        stderr = proc.stderr.read()
    failed = stderr.count("Could not connect") + stderr.count("Error")
    return {
        "hosts": n,
        "peak_fds": peak_fds,
        "peak_rss_mb": round(peak_rss / 1024, 1),
        "seconds": round(time.monotonic() - started, 2),
        "exit": proc.returncode,
        "failed_lines": failed,
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python3 -m tests.bench.pool")
    parser.add_argument("--prefix", default=os.environ.get("ROBOT_LAB_PREFIX", "bench"))
    parser.add_argument("--hosts", type=int, nargs="+", default=[1, 10, 30])
    parser.add_argument("--hold", type=float, default=3.0, help="seconds each command keeps its channel open")
    args = parser.parse_args(argv)
    from tests.lab import state as lab_state

    state = lab_state.load(args.prefix)
    rows = [measure(state, n, args.hold) for n in args.hosts]
    for row in rows:
        print(json.dumps(row))
    if len(rows) > 1:
        a, b = rows[0], rows[-1]
        per_host_fds = (b["peak_fds"] - a["peak_fds"]) / (b["hosts"] - a["hosts"])
        per_host_mb = (b["peak_rss_mb"] - a["peak_rss_mb"]) / (b["hosts"] - a["hosts"])
        print(
            json.dumps(
                {
                    "fds_per_host": round(per_host_fds, 2),
                    "rss_mb_per_host": round(per_host_mb, 2),
                    "base_fds": a["peak_fds"],
                    "base_rss_mb": a["peak_rss_mb"],
                }
            )
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
