"""The operator side's scaling curve: a no-op rerun and `robotfleet status` at
N = 1 .. 1,000 robots, time, CPU, memory and open files of the operator's process.

    python3 -m tests.bench.scale [--prefix perf] [--hosts 1 10 50 100 200] [--runs 3] [--write]

What is measured is the operator's process, so most hosts are light: one
container (``<prefix>light-hosts``, the lab's host image, host network) runs
one sshd listening on a port per light host (127.0.0.1:30001..), and every
command it is sent answers with what a converged lab robot answered.  That
is a STAND-IN for the whole host (no dpkg, systemd or Docker behind it):
the snapshot and status outputs are captured from the running lab's robot4
(converged first by the caller) and replayed.  Up to three real lab robots
(robot4..6 of ``--prefix``) are in every run from N = 10 on (N = 1 is
robot4 alone), so each figure also shows the real robots' answers.

For each N and each command, ``--runs`` runs (median, min–max), each
sampled every 20 ms for the process's peak resident memory and open file
descriptors; the no-op's SSH commands per host are counted (it must stay
one).  Load average before each run goes beside it (tests/bench/hygiene).
--write puts SCALE.json and scale.png (matplotlib, the bench extra) beside
this file.  Asserts nothing.  How to run it, up to 1,000 hosts: --help.
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

from tests.bench import hygiene
from tests.bench.pool import sample
from tests.bench.roundtrips import COUNTING
from tests.bench.scale_fit import fit, plot, summarize
from tests.fixtures import pyinfra_argv

ROOT = Path(__file__).resolve().parents[2]
HERE = Path(__file__).resolve().parent
# Below Linux's ephemeral range (32768-60999): an outgoing connection's own
# port must not take a light host's.
PORT_BASE = 30000
MAX_HOSTS = 1000
ANCHORS = ("robot4", "robot5", "robot6")
REPLAY = """#!/bin/sh
case "$SSH_ORIGINAL_COMMAND" in
  *@@@robot-fleet-status*) exec cat /light/status ;;
  *) exec cat /light/snapshot ;;
esac
"""

# Runs inside the pyinfra or status process: each command's stdout, by host.
CAPTURING = r"""
import atexit, json, sys
from pyinfra.connectors.ssh import SSHConnector
REPORT = sys.argv.pop(1)
seen = {}
original = SSHConnector.run_shell_command
def run_shell_command(self, command, *args, **kwargs):
    status, output = original(self, command, *args, **kwargs)
    seen.setdefault(self.host.name, []).append(output.stdout)
    return status, output
SSHConnector.run_shell_command = run_shell_command
atexit.register(lambda: json.dump(seen, open(REPORT, "w")))
if sys.argv[1] == "status":
    from robotfleet.__main__ import main
    sys.exit(main(sys.argv[1:]))
from pyinfra_cli.main import main
sys.argv[0] = "pyinfra"
main()
"""


def log(message: str) -> None:
    print(f"[scale] {message}", file=sys.stderr, flush=True)


class Scale:
    def __init__(self, prefix: str, workdir: Path, cpus: str = "1", memory: str = "2g"):
        from tests.lab import state as lab_state

        self.prefix, self.workdir, self.cpus, self.memory = prefix, workdir, cpus, memory
        self.lab = lab_state.load(prefix)
        self.container = f"{prefix}light-hosts"
        self.light_dir = ROOT / ".lab" / f"{prefix}light"
        self.light_dir.mkdir(parents=True, exist_ok=True)

    # --- the fleet file and the inventory's input -------------------------------
    def fleet(self, names: list[str]) -> Path:
        """lab.yaml's settings (placeholders filled as inventories/lab.py
        fills them) for robots ``names``, none with sensors."""
        from robotfleet.fleet import loader, yaml12

        text = (ROOT / "inventories" / "lab.yaml").read_text()
        fingerprint = (
            json.loads((Path(self.lab["mirror_dir"]) / "manifest.json").read_text())["fingerprint"]
            if (Path(self.lab["mirror_dir"]) / "manifest.json").exists()
            else json.loads((Path(self.lab["mirror_dir"]).parent / "manifest.json").read_text())["fingerprint"]
        )
        for key, value in {
            "@registry@": self.lab["registry"],
            "@mirror@": self.lab["mirror_url"],
            "@mirror_fingerprint@": fingerprint,
        }.items():
            text = text.replace(key, value)
        raw = loader.load(text)
        doc = {"all": raw["all"], "robots": {"vars": raw["robots"]["vars"], "hosts": {name: {} for name in names}}}
        path = self.workdir / f"fleet-{len(names)}.yaml"
        path.write_text(yaml12.dump(doc))
        return path

    def spec(self, names: list[str]) -> Path:
        ports = {h["name"]: h["port"] for h in self.lab["hosts"]}
        ports.update({name: PORT_BASE + int(name[5:]) for name in names if name.startswith("light")})
        path = self.workdir / f"hosts-{len(names)}.json"
        path.write_text(
            json.dumps(
                {
                    "fleet": str(self.fleet(names)),
                    "ports": {n: ports[n] for n in names},
                    "ssh_user": self.lab["ssh_user"],
                    "ssh_key": self.lab["ssh_key"],
                    "known_hosts": str(self.light_dir / "known_hosts"),
                }
            )
        )
        return path

    def env(self, spec: Path) -> dict:
        return dict(os.environ, ROBOT_SCALE_HOSTS=str(spec), PYINFRA_PROGRESS="off")

    # --- what a converged robot answers ------------------------------------------
    def capture(self) -> None:
        """The snapshot and status outputs of the first anchor, converged (a deploy first)."""
        spec = self.spec([ANCHORS[0]])
        self._known_hosts(light=0)
        inventory = "tests/bench/scale_inventory.py"
        subprocess.run(
            pyinfra_argv(str(self.workdir / "c.json"), "-y", inventory, "deploy.py", setup=COUNTING),
            cwd=ROOT,
            env=self.env(spec),
            capture_output=True,
            text=True,
            check=True,
        )
        answers = {}
        for kind, args in (("snapshot", ["-y", inventory, "deploy.py"]), ("status", ["status", inventory])):
            report = self.workdir / f"capture-{kind}.json"
            subprocess.run(
                [sys.executable, "-c", CAPTURING, str(report), *args],
                cwd=ROOT,
                env=self.env(spec),
                capture_output=True,
                text=True,
                check=True,
            )
            outputs = json.loads(report.read_text())
            (answer,) = next(iter(outputs.values()))  # one command: the snapshot, or the status
            answers[kind] = answer
            (self.light_dir / kind).write_text(answer + "\n")
        (self.light_dir / "replay").write_text(REPLAY)
        (self.light_dir / "replay").chmod(0o755)

    # --- the light hosts -----------------------------------------------------------
    def start(self, count: int) -> None:
        self.stop()
        # One sshd per 16 ports (OpenSSH's MAX_LISTEN_SOCKS).
        for old in self.light_dir.glob("sshd_config.*"):
            old.unlink()
        ports = [PORT_BASE + i for i in range(1, count + 1)]
        for index in range(0, len(ports), 16):
            listen = "\n".join(f"Port {port}" for port in ports[index : index + 16])
            (self.light_dir / f"sshd_config.{index // 16:03d}").write_text(
                f"{listen}\nListenAddress 127.0.0.1\nHostKey /etc/ssh/ssh_host_ed25519_key\n"
                "AuthorizedKeysFile /light/authorized_keys\nPasswordAuthentication no\n"
                "KbdInteractiveAuthentication no\n"
                "UsePAM no\nForceCommand /light/replay\nMaxStartups 1000:30:1000\nPerSourcePenalties no\n"
                "LogLevel ERROR\nStrictModes no\n"
            )
        (self.light_dir / "authorized_keys").write_text(Path(self.lab["ssh_key"] + ".pub").read_text())
        image = subprocess.run(
            ["docker", "inspect", "-f", "{{.Config.Image}}", f"{self.prefix}-robot1"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
        script = (
            "mkdir -p /run/sshd && ssh-keygen -q -t ed25519 -N '' -f /etc/ssh/ssh_host_ed25519_key <<< y "
            ">/dev/null 2>&1;"
            " for f in /light/sshd_config.*; do /usr/sbin/sshd -f $f || exit 1; done; exec sleep infinity"
        )
        subprocess.run(
            [
                "docker",
                "run",
                "-d",
                "--name",
                self.container,
                "--network",
                "host",
                "--memory",
                self.memory,
                "--cpus",
                self.cpus,
                "-v",
                f"{self.light_dir}:/light:ro",
                "--entrypoint",
                "bash",
                image,
                "-c",
                script,
            ],
            capture_output=True,
            text=True,
            check=True,
        )
        for _ in range(100):
            key = subprocess.run(
                ["docker", "exec", self.container, "cat", "/etc/ssh/ssh_host_ed25519_key.pub"],
                capture_output=True,
                text=True,
            )
            if key.returncode == 0 and key.stdout and self._listening(PORT_BASE + count):
                break
            time.sleep(0.2)
        deaf = [port for port in ports if not self._listening(port)]
        if deaf:
            raise RuntimeError(f"light hosts: nothing listens on 127.0.0.1 port(s) {deaf[:10]}")
        self._known_hosts(count, key.stdout)

    @staticmethod
    def _listening(port: int) -> bool:
        import socket

        with socket.socket() as s:
            s.settimeout(0.5)
            return s.connect_ex(("127.0.0.1", port)) == 0

    def _known_hosts(self, light: int, public_key: str = "") -> None:
        lines = Path(self.lab["known_hosts"]).read_text().splitlines()
        if light:
            key_type, key = public_key.split()[:2]
            lines += [f"[127.0.0.1]:{PORT_BASE + i} {key_type} {key}" for i in range(1, light + 1)]
        (self.light_dir / "known_hosts").write_text("\n".join(lines) + "\n")

    def stop(self) -> None:
        subprocess.run(["docker", "rm", "-f", self.container], capture_output=True)

    def light_memory_mb(self) -> float | None:
        out = (
            subprocess.run(
                ["docker", "stats", "--no-stream", "--format", "{{.MemUsage}}", self.container],
                capture_output=True,
                text=True,
            )
            .stdout.split("/")[0]
            .strip()
        )
        for unit, scale in (("GiB", 1024), ("MiB", 1), ("KiB", 1 / 1024)):
            if out.endswith(unit):
                return round(float(out[: -len(unit)]) * scale, 1)
        return None

    # --- one measured run ------------------------------------------------------------
    def run(self, kind: str, spec: Path, extra: list[str]) -> dict:
        report = self.workdir / "counts.json"
        inventory = "tests/bench/scale_inventory.py"
        if kind == "noop":
            argv = pyinfra_argv(str(report), "-y", *extra, inventory, "deploy.py", setup=COUNTING)
        else:
            argv = [sys.executable, "-m", "robotfleet", "status", inventory, *extra]
        started, cpu = time.monotonic(), _children_cpu()
        # Output to files: a pipe nobody reads while the process runs fills up
        # (pyinfra's output for 200 hosts is larger than a pipe's buffer).
        with open(self.workdir / "out", "w+") as out_file, open(self.workdir / "err", "w+") as err_file:
            proc = subprocess.Popen(argv, cwd=ROOT, env=self.env(spec), stdout=out_file, stderr=err_file)
            peak_rss = peak_fds = 0
            while proc.poll() is None:
                fds, rss = sample(proc.pid)
                peak_rss, peak_fds = max(peak_rss, rss), max(peak_fds, fds)
                time.sleep(0.02)
            out_file.seek(0)
            err_file.seek(0)
            out, err = out_file.read(), err_file.read()
        wall = time.monotonic() - started
        row = {
            "seconds": round(wall, 3),
            "cpu_seconds": round(_children_cpu() - cpu, 3),
            "peak_rss_mb": round(peak_rss / 1024, 1),
            "peak_fds": peak_fds,
            "exit": proc.returncode,
        }
        if kind == "noop":
            counts = json.loads(report.read_text()) if report.exists() else {}
            row["commands_per_host"] = max((c.get("commands", 0) for c in counts.values()), default=None)
            row["hosts_answered"] = len(counts)
            row["changed"] = "Success" in out and _changes(out)
        else:
            row["rows"] = sum(1 for line in out.splitlines()[1:] if line.strip())
        if proc.returncode != 0:
            log(f"{kind} exit {proc.returncode}: {err[-600:]}")
        return row


def _changes(output: str) -> bool:
    """Whether pyinfra's results table counts any operation as changed."""
    for line in output.splitlines():
        if line.strip().startswith("Grand total"):
            cells = line.split()
            return cells[-3] != "-"  # Success column
    return True


def _children_cpu() -> float:
    import resource

    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def names_for(n: int) -> list[str]:
    if n == 1:
        return [ANCHORS[0]]
    anchors = list(ANCHORS[: min(len(ANCHORS), n)])
    return anchors + [f"light{i:03d}" for i in range(1, n - len(anchors) + 1)]


HOW = """\
Before it: the lab up with the anchors (robot4..6 by default), e.g.
  python3 -m tests.lab up --prefix perf --robots 6 --laptops 0
The first anchor is converged by the benchmark itself (a deploy), then its
answers are replayed by the light hosts: STAND-INS, one container of sshds.

Up to 1,000 hosts (light001..light997 beside the three anchors, ports
127.0.0.1:30001 on): the operator process raises its open-file limit to
about 3 per host itself; the hard limit (ulimit -Hn) must allow 3,100, and
the stand-ins' sshds want more than the default one CPU and 2 GB:
  python3 -m tests.bench.scale --hosts 1 10 100 250 500 1000 --runs 3 \\
      --light-cpus 2 --light-memory 6g --write
Idle machine only for figures (tests/bench/hygiene waits for a low load);
a quick check that it runs: --hosts 20 --runs 1.  Take the lab down after:
  python3 -m tests.lab down --prefix perf
"""


def main(argv=None) -> int:
    global ANCHORS
    parser = argparse.ArgumentParser(
        prog="python3 -m tests.bench.scale",
        description=__doc__.splitlines()[0],
        epilog=HOW,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--prefix", default=os.environ.get("ROBOT_LAB_PREFIX", "perf"))
    parser.add_argument(
        "--hosts", type=int, nargs="+", default=[1, 10, 50, 100, 200], help="the sizes N of the curve (1 to 1000)"
    )
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument(
        "--parallel",
        type=int,
        nargs="*",
        default=[],
        help="also run the no-op at the largest N with pyinfra --parallel P",
    )
    parser.add_argument(
        "--anchors",
        nargs="+",
        default=list(ANCHORS),
        metavar="ROBOT",
        help="the real lab robots in every run (default: robot4 robot5 robot6)",
    )
    parser.add_argument("--light-cpus", default="1", help="CPUs of the light hosts' container (docker --cpus)")
    parser.add_argument("--light-memory", default="2g", help="its memory (docker --memory)")
    parser.add_argument("--write", action="store_true", help="write SCALE.json and scale.png beside this file")
    args = parser.parse_args(argv)
    ANCHORS = tuple(args.anchors)
    if not all(1 <= n <= MAX_HOSTS for n in args.hosts):
        parser.error(
            f"--hosts: each N from 1 to {MAX_HOSTS} (the light hosts' ports end below Linux's ephemeral range)"
        )
    import datetime

    with tempfile.TemporaryDirectory() as tmp:
        scale = Scale(args.prefix, Path(tmp), args.light_cpus, args.light_memory)
        log(f"capturing {ANCHORS[0]}'s converged answers")
        scale.capture()
        curve: dict[str, list] = {"noop": [], "status": []}
        extra_rows = []
        loads = []
        try:
            for n in args.hosts:
                names = names_for(n)
                light = sum(1 for name in names if name.startswith("light"))
                scale.start(max(light, 1))
                spec = scale.spec(names)
                scale.run("noop", spec, [])  # first contact of this size: warm
                for kind in ("noop", "status"):
                    runs = []
                    for index in range(args.runs):
                        load, idle = hygiene.wait(f"{kind} N={n}", first=index == 0)
                        loads.append(load)
                        runs.append({**scale.run(kind, spec, []), "load": load, "idle": idle})
                    row = {
                        "hosts": n,
                        "real": len(names) - light,
                        "light": light,
                        "seconds": summarize([r["seconds"] for r in runs]),
                        "peak_rss_mb": summarize([r["peak_rss_mb"] for r in runs]),
                        "peak_fds": summarize([r["peak_fds"] for r in runs]),
                        "cpu_seconds": summarize([r["cpu_seconds"] for r in runs]),
                        "loads": [r["load"] for r in runs],
                        "idle": all(r["idle"] for r in runs),
                        "runs": runs,
                        "light_hosts_memory_mb": scale.light_memory_mb(),
                    }
                    curve[kind].append(row)
                    log(
                        f"N={n} {kind}: {row['seconds']} s, CPU {row['cpu_seconds']['median']} s "
                        f"({row['cpu_seconds']['median'] / n * 1000:.1f} ms/robot), {row['peak_rss_mb']['median']} MB, "
                        f"{row['peak_fds']['median']} fds, loads {row['loads']}; last run: "
                        + ", ".join(
                            f"{k} {v}"
                            for k, v in runs[-1].items()
                            if k in ("exit", "commands_per_host", "hosts_answered", "changed", "rows")
                        )
                    )
                if n == max(args.hosts):
                    for parallel in args.parallel:
                        runs = []
                        for index in range(args.runs):
                            load, idle = hygiene.wait(f"noop N={n} --parallel {parallel}", first=index == 0)
                            loads.append(load)
                            runs.append(
                                {**scale.run("noop", spec, ["--parallel", str(parallel)]), "load": load, "idle": idle}
                            )
                        extra_rows.append(
                            {
                                "hosts": n,
                                "parallel": parallel,
                                "seconds": summarize([r["seconds"] for r in runs]),
                                "peak_rss_mb": summarize([r["peak_rss_mb"] for r in runs]),
                                "peak_fds": summarize([r["peak_fds"] for r in runs]),
                                "runs": runs,
                            }
                        )
                        log(f"N={n} noop --parallel {parallel}: {extra_rows[-1]['seconds']}")
        finally:
            scale.stop()
    fits = {
        kind: {
            key: fit([(r["hosts"], r[key]["median"]) for r in rows])
            for key in ("seconds", "cpu_seconds", "peak_rss_mb", "peak_fds")
        }
        for kind, rows in curve.items()
    }
    result = {
        "conditions": {
            "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
            "commit": subprocess.run(
                ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=ROOT
            ).stdout.strip(),
            "cpus": os.cpu_count(),
            "load_range": f"{min(loads):.1f}–{max(loads):.1f}",
            "ulimit_n": __import__("resource").getrlimit(__import__("resource").RLIMIT_NOFILE)[0],
        },
        "curve": curve,
        "fits": fits,
        "parallel": extra_rows,
    }
    print(
        json.dumps(
            {"fits": fits, "parallel": [{k: v for k, v in r.items() if k != "runs"} for r in extra_rows]}, indent=2
        )
    )
    if args.write:
        (HERE / "SCALE.json").write_text(json.dumps(result, indent=2) + "\n")
        plot(result, HERE / "scale.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
