"""Benchmark: round trips a run waits for, per host (issue 51, item 4).

    python3 -m tests.bench.rtt [--prefix bench-rtt] [--rtts 0,100,300] [--runs 3] [--keep] [--write]

A lab of one fresh robot per round-trip time (tests/lab), each reached
through the lab's proxy (tests/lab/linkproxy.py) that delays every chunk
half the round trip each way.  Timed, with the mission's command
(``pyinfra -y inventories/lab.py deploy.py --limit ROBOT``): a first
provisioning (robot N's own, at the N-th round trip), then on robot1 at
each round trip a no-op rerun and a one-tag update (1.0 and 1.1 in turn),
beside ``pyinfra exec -- true`` and Ansible's ``ansible ROBOT -m command -a
true`` (ansible-core, the test extra; a fresh ControlPath each run, as a
first invocation has).  Each figure but the first provisioning is the
median of --runs.  **Sequential round trips per host** = (time at the
round trip - time at 0) / the round trip: what the run waited on the link,
whatever its CPU.  Nothing is asserted; --write puts the table in
tests/bench/RESULTS-rtt.json (and prints what docs/reference/benchmarks.md
shows).  Run it with /work/bin/e2e-slot --both and the load under 1.5.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from tests.bench import hygiene
from tests.fixtures import ROOT, pyinfra_argv
from tests.lab.linkproxy import Link, through

HERE = Path(__file__).resolve().parent
TAG = 'payload_image: "@registry@/ros/payload:1.0"'
ROWS = (
    ("first", "first provisioning (a fresh robot)"),
    ("noop", "no-op rerun"),
    ("update", "one-tag update"),
    ("exec", "`pyinfra exec -- true`"),
    ("ansible", "`ansible -m command -a true`"),
)


def timed(argv: list[str], env: dict) -> tuple[float, int, str]:
    started = time.monotonic()
    done = subprocess.run(argv, cwd=ROOT, env=env, capture_output=True, text=True, timeout=1800)
    return time.monotonic() - started, done.returncode, done.stderr[-2000:] + done.stdout[-2000:]


def fleet_file(directory: Path, tag: str) -> Path:
    path = directory / f"lab-{tag}.yaml"
    text = (ROOT / "inventories" / "lab.yaml").read_text()
    path.write_text(text.replace(TAG, f'payload_image: "@registry@/ros/payload:{tag}"', 1))
    return path


def ansible_inventory(directory: Path, state: dict, known_hosts: str, links: dict) -> Path:
    path = directory / "ansible.ini"
    common = f"-o UserKnownHostsFile={known_hosts} -o StrictHostKeyChecking=yes"
    path.write_text(
        "".join(
            f"{name} ansible_host=127.0.0.1 ansible_port={link.port} ansible_user={state.get('ssh_user', 'ops')} "
            f"ansible_ssh_private_key_file={state['ssh_key']} ansible_python_interpreter=/usr/bin/python3 "
            f"ansible_ssh_common_args='{common}'\n"
            for name, link in links.items()
        )
    )
    return path


def sample(label: str, argv: list[str], env: dict, runs: int, fresh=None) -> dict:
    """The median of ``runs`` timed runs of ``argv`` (``fresh()``: the environment's changes for each)."""
    seconds, loads = [], []
    for index in range(runs):
        loads.append(hygiene.wait(label, index == 0)[0])
        took, code, said = timed(argv, {**env, **(fresh() if fresh else {})})
        if code:
            raise SystemExit(f"[bench] {label}: exit {code}: {said}")
        seconds.append(took)
    figure = {"seconds": round(statistics.median(seconds), 2), "spread": round(max(seconds) - min(seconds), 2)}
    print(f"[bench] {label}: {figure['seconds']:.2f} s (spread {figure['spread']:.2f}, load {max(loads):.2f})")
    return {**figure, "load": max(loads)}


def measure(prefix: str, rtts: list[int], runs: int) -> dict:
    from tests.lab import hosts

    hosts.down(prefix)
    state = hosts.up(prefix, robots=len(rtts), laptops=0)
    robots = [h["name"] for h in state["hosts"] if h["group"] == "robots"]
    links = {name: Link(next(h["port"] for h in state["hosts"] if h["name"] == name)) for name in robots}
    work = Path(tempfile.mkdtemp(prefix="bench-rtt-"))
    try:
        base = dict(os.environ, ROBOT_LAB_PREFIX=prefix, PYINFRA_PROGRESS="off", **through(state, links))
        deploy = pyinfra_argv("-y", "inventories/lab.py", "deploy.py", "--limit")
        found: dict = {row: {} for row, _ in ROWS}
        for robot, rtt in zip(robots, rtts):
            links[robot].delay = rtt / 2000
            hygiene.wait(f"first provisioning of {robot} at {rtt} ms", True)
            took, code, said = timed([*deploy, robot], {**base, "ROBOT_LAB_FLEET": str(fleet_file(work, "1.0"))})
            if code:
                raise SystemExit(f"[bench] first provisioning of {robot}: exit {code}: {said}")
            found["first"][rtt] = {"seconds": round(took, 2), "spread": 0.0, "load": hygiene.load()}
            print(f"[bench] first provisioning of {robot} at {rtt} ms: {took:.1f} s")
        one = robots[0]
        current = ["1.0"]  # the tag robot1 runs

        def flip() -> dict:
            current[0] = "1.1" if current[0] == "1.0" else "1.0"
            return {"ROBOT_LAB_FLEET": str(fleet_file(work, current[0]))}

        inventory = ansible_inventory(work, state, base["ROBOT_LAB_KNOWN_HOSTS"], {one: links[one]})
        ansible = shutil.which("ansible", path=str(Path(sys.executable).parent)) or shutil.which("ansible")
        for rtt in rtts:
            links[one].delay = rtt / 2000
            same = {**base, "ROBOT_LAB_FLEET": str(fleet_file(work, current[0]))}
            found["noop"][rtt] = sample(f"no-op rerun at {rtt} ms", [*deploy, one], same, runs)
            found["update"][rtt] = sample(f"one-tag update at {rtt} ms", [*deploy, one], base, runs, flip)
            exec_true = pyinfra_argv("-y", "inventories/lab.py", "exec", "--limit", one)
            exec_true += ["--", "true"]
            found["exec"][rtt] = sample(f"pyinfra exec -- true at {rtt} ms", exec_true, same, runs)
            if ansible:
                found["ansible"][rtt] = sample(
                    f"ansible -m command -a true at {rtt} ms",
                    [ansible, one, "-i", str(inventory), "-m", "command", "-a", "true"],
                    {**base, "ANSIBLE_HOST_KEY_CHECKING": "True"},
                    runs,
                    lambda: {"ANSIBLE_SSH_CONTROL_PATH_DIR": tempfile.mkdtemp(dir=work)},
                )
        return {"rtts": rtts, "runs": runs, "figures": found}
    finally:
        for link in links.values():
            link.close()
        shutil.rmtree(work, ignore_errors=True)


def table(results: dict) -> str:
    """The markdown table: seconds at each round trip, then round trips per host."""
    rtts = results["rtts"]
    slow = [r for r in rtts if r]
    head = ["run", *(f"{r} ms (s)" for r in rtts), *(f"round trips at {r} ms" for r in slow)]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" + "---:|" * (len(head) - 1)]
    for key, label in ROWS:
        row = {int(r): v for r, v in results["figures"].get(key, {}).items()}
        if not row:
            continue
        cells = [f"{row[r]['seconds']:.1f}" if r in row else "-" for r in rtts]
        trips = [
            f"{(row[r]['seconds'] - row[rtts[0]]['seconds']) / (r / 1000):.1f}" if r in row and rtts[0] in row else "-"
            for r in slow
        ]
        lines.append("| " + " | ".join([label, *cells, *trips]) + " |")
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--prefix", default="bench-rtt")
    parser.add_argument("--rtts", default="0,100,300", help="round-trip times in ms, the first the baseline (0)")
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--keep", action="store_true", help="leave the lab up")
    parser.add_argument("--write", action="store_true", help="write tests/bench/RESULTS-rtt.json")
    args = parser.parse_args()
    rtts = [int(r) for r in args.rtts.split(",")]
    try:
        results = measure(args.prefix, rtts, args.runs)
    finally:
        if not args.keep:
            from tests.lab import hosts

            hosts.down(args.prefix)
    print("\n" + table(results))
    if args.write:
        (HERE / "RESULTS-rtt.json").write_text(json.dumps(results, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
