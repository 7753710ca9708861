"""Measurement: does `--use-sudo-password` show the password to other users
of the host (issue 8 item 11)?  Prints figures; asserts nothing.

    python3 -m tests.bench.sudo_password [--prefix lab] [--host laptop1] [--commands 100]

pyinfra 3 runs every sudo command as
`env SUDO_ASKPASS=<script> PYINFRA_SUDO_PASSWORD=<password> sudo -H -A -k sh -c ...`
(pyinfra/connectors/util.py, make_unix_command): the password is in the
argv of the login shell that sshd starts (`<shell> -c '<that line>'`) and
of `env`, until `env` execs sudo.  Any local user can read argv
(/proc/<pid>/cmdline, `ps`) unless /proc is mounted with hidepid.

On a running lab host this makes a user `sudopw` whose sudo needs a
password, starts a sampler as `nobody` that reads every process's argv in a
loop, runs `--commands` sudo commands through the real pyinfra CLI with
`--use-sudo-password` (the password given on stdin, as at the prompt), and
prints how many of the sampler's sweeps saw the password and in what.
"""

from __future__ import annotations

import argparse
import base64
import json
import os
import secrets
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
USER = "sudopw"
SAMPLES = "/var/tmp/sudopw-samples.json"

SAMPLER = r"""
import json, os, sys, time
marker, seconds, out = sys.argv[1], float(sys.argv[2]), sys.argv[3]
sweeps, hits, seen, me = 0, 0, {}, str(os.getpid())
end = time.monotonic() + seconds
while time.monotonic() < end and not os.path.exists(out + ".stop"):
    sweeps += 1
    hit = False
    for pid in os.listdir("/proc"):
        if not pid.isdigit() or pid == me:
            continue
        try:
            with open(f"/proc/{pid}/cmdline", "rb") as f:
                argv = f.read().split(b"\0")
        except OSError:
            continue
        if any(marker.encode() in a for a in argv):
            hit = True
            seen[argv[0].decode(errors="replace")] = seen.get(argv[0].decode(errors="replace"), 0) + 1
    hits += hit
json.dump({"sweeps": sweeps, "sweeps_with_password": hits, "seen_in": seen}, open(out, "w"))
"""


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--prefix", default=os.environ.get("ROBOT_LAB_PREFIX", "lab"))
    parser.add_argument("--host", default="laptop1")
    parser.add_argument("--commands", type=int, default=50)
    args = parser.parse_args()

    from tests.lab.state import exec_in

    state = json.loads((ROOT / ".lab" / args.prefix / "state.json").read_text())
    port = next(h["port"] for h in state["hosts"] if h["name"] == args.host)
    password = "pw-" + secrets.token_hex(8)
    pubkey = Path(state["ssh_key"] + ".pub").read_text().strip()

    def root(command: str) -> str:
        code, out = exec_in(args.prefix, args.host, command)
        if code:
            sys.exit(f"{args.host}: {command}: {out}")
        return out

    root(f"id {USER} >/dev/null 2>&1 || useradd -m -s /bin/bash {USER}")
    root(f"echo '{USER}:{password}' | chpasswd")
    root(f"echo '{USER} ALL=(ALL) ALL' > /etc/sudoers.d/{USER} && chmod 440 /etc/sudoers.d/{USER}")
    root(
        f"install -d -m 700 -o {USER} /home/{USER}/.ssh && echo '{pubkey}' > /home/{USER}/.ssh/authorized_keys"
        f" && chown {USER} /home/{USER}/.ssh/authorized_keys"
    )
    shell = root(f"getent passwd {USER} | cut -d: -f7").strip()

    with tempfile.TemporaryDirectory() as tmp:
        inventory = Path(tmp) / "inventory.py"
        inventory.write_text(
            f"hosts = [({args.host!r}, {{'ssh_hostname': '127.0.0.1', 'ssh_port': {port}, 'ssh_user': {USER!r},"
            f" 'ssh_key': {state['ssh_key']!r}, 'ssh_known_hosts_file': {state['known_hosts']!r},"
            f" 'ssh_strict_host_key_checking': 'yes', 'ssh_allow_agent': False, 'ssh_look_for_keys': False}})]\n"
        )
        deploy = Path(tmp) / "deploy.py"
        deploy.write_text(
            "from pyinfra.operations import server\n"
            f"for i in range({args.commands}):\n"
            "    server.shell(name=f'sudo command {i}', commands=[f'true {i}'], _sudo=True)\n"
        )
        seconds = 60 + args.commands * 2
        sampler = base64.b64encode(SAMPLER.encode()).decode()
        root(
            f"rm -f {SAMPLES} {SAMPLES}.stop; echo {sampler} | base64 -d > {SAMPLES}.py && "
            f"systemd-run --unit=sudopw-sampler --collect --uid=nobody python3 {SAMPLES}.py "
            f"{password} {seconds} {SAMPLES}"
        )
        started = time.monotonic()
        proc = subprocess.run(
            [sys.executable, "-m", "pyinfra", "-y", "--use-sudo-password", str(inventory), str(deploy)],
            input=password + "\n",
            capture_output=True,
            text=True,
            cwd=tmp,
            start_new_session=True,
            env=dict(os.environ, PYINFRA_PROGRESS="off"),
            timeout=seconds,
        )
        ran = time.monotonic() - started
        root(f"touch {SAMPLES}.stop; for i in $(seq 100); do [ -s " + SAMPLES + " ] && break; sleep 0.1; done; true")
        samples = json.loads(root(f"cat {SAMPLES}") or "{}")

    print(
        f"host {args.host} (login shell {shell}), pyinfra exit {proc.returncode}, "
        f"{args.commands} sudo commands in {ran:.1f} s"
    )
    if proc.returncode:
        print(proc.stderr[-2000:])
    print(f"password in pyinfra's output: {'yes' if password in proc.stdout + proc.stderr else 'no'}")
    print(
        f"sampler (as nobody): {samples.get('sweeps')} sweeps of /proc/*/cmdline, "
        f"{samples.get('sweeps_with_password')} saw the password, in: {samples.get('seen_in')}"
    )
    root(f"rm -f /etc/sudoers.d/{USER} {SAMPLES} {SAMPLES}.stop {SAMPLES}.py; userdel -r {USER} 2>/dev/null; true")


if __name__ == "__main__":
    main()
