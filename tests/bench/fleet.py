"""The fleet benchmark: every speed figure next to a floor measured in the
same run on the same simulated hosts.  Prints figures and returns them;
asserts nothing (timings stay out of the test suite).

For N robots (no laptop), on a lab of its own:
  floors   N parallel `ssh true`; `pyinfra exec -- true`; Docker's documented
           apt install of the five packages + one `docker pull` of the payload
           + the payload's health window, by hand over SSH on fresh hosts
  fresh    the first deploy.py run (hosts reset to fresh first)
  no-op    converged reruns (median) and SSH commands per host
  rollout  python3 -m engine rollout of the whole fleet (canary 1, batch 50%)
  update   all N robots to another tag, then one robot; each robot's payload
           downtime (old container dies -> new one starts, from docker events)
  crash    one robot to the crash-looping tag: time until the old release
           runs again
"""

from __future__ import annotations

import json
import os
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from tests.bench.roundtrips import COUNTING_PYINFRA

ROOT = Path(__file__).resolve().parents[2]
PYINFRA = "import sys; from pyinfra_cli.main import main; sys.argv[0] = 'pyinfra'; main()"
ALL_TAG = 'payload_image: "@registry@/ros/payload:1.0"'


def log(message: str) -> None:
    print(f"[bench] {message}", file=sys.stderr, flush=True)


class Bench:
    def __init__(self, prefix: str, robots: int, workdir: Path):
        self.prefix, self.n, self.workdir = prefix, robots, workdir
        self.state: dict = {}

    # --- lab ------------------------------------------------------------------
    def up(self, fresh: bool = False) -> None:
        from tests.lab import hosts

        if fresh:
            hosts.down(self.prefix)
        self.state = hosts.up(self.prefix, robots=self.n, laptops=0)
        self.robots = [h["name"] for h in self.state["hosts"]]

    def down(self) -> None:
        from tests.lab import hosts

        hosts.down(self.prefix)

    def fleet(self, tag: str) -> Path:
        text = (ROOT / "inventories" / "lab.yaml").read_text().replace(
            ALL_TAG, f'payload_image: "@registry@/ros/payload:{tag}"', 1)
        # lab.yaml declares robot1-3; the lab's inventory only has declared hosts.
        extra = "".join(f"    robot{i}: {{}}\n" for i in range(4, self.n + 1))
        text = text.replace("\nlaptops:", "\n" + extra + "\nlaptops:", 1) if extra else text
        path = self.workdir / f"lab-{tag}.yaml"
        path.write_text(text)
        return path

    def env(self, tag: str = "1.0") -> dict:
        return dict(os.environ, ROBOT_LAB_PREFIX=self.prefix, ROBOT_LAB_FLEET=str(self.fleet(tag)),
                    PYINFRA_PROGRESS="off", ROBOT_ROLLOUT_DIR=str(self.workdir / "rollout"))

    def ssh(self, host: str, command: str) -> list[str]:
        port = next(h["port"] for h in self.state["hosts"] if h["name"] == host)
        return ["ssh", "-q", "-i", self.state["ssh_key"], "-p", str(port), "-o", "BatchMode=yes",
                "-o", f"UserKnownHostsFile={self.state['known_hosts']}", "-o", "StrictHostKeyChecking=yes",
                f"{self.state['ssh_user']}@127.0.0.1", command]

    def parallel_ssh(self, command: str) -> float:
        started = time.monotonic()
        procs = [subprocess.Popen(self.ssh(h, command), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
                 for h in self.robots]
        errors = [p.communicate()[1] for p in procs if p.wait() != 0]
        seconds = time.monotonic() - started
        if errors:
            raise RuntimeError(f"ssh {command[:60]}...: {errors[0][-500:]}")
        return seconds

    def pyinfra(self, *args: str, tag: str = "1.0", count: bool = False) -> tuple[float, int, dict]:
        report = self.workdir / "counts.json"
        prog = [sys.executable, "-c", COUNTING_PYINFRA, str(report)] if count else [sys.executable, "-c", PYINFRA]
        started = time.monotonic()
        proc = subprocess.run([*prog, "-y", "inventories/lab.py", *args], cwd=ROOT, env=self.env(tag),
                              capture_output=True, text=True)
        seconds = time.monotonic() - started
        if proc.returncode != 0:
            log(f"pyinfra {' '.join(args)} exit {proc.returncode}: {proc.stderr[-800:]}")
        counts = json.loads(report.read_text()) if count and report.exists() else {}
        return seconds, proc.returncode, counts

    def events(self, host: str, since: float) -> list[tuple[float, str, str]]:
        """(time, action, image) of the payload's container events since ``since``."""
        # The lab payload's version label: the image attribute is a digest.
        fmt = '{{.TimeNano}} {{.Action}} {{index .Actor.Attributes "org.opencontainers.image.version"}}'

        out = subprocess.run(self.ssh(host, (
            f"sudo docker events --since {since:.3f} --until $(date +%s.%N) --filter type=container "
            f"--filter label=com.docker.compose.project=robot-payload --format {shlex.quote(fmt)}")),
            capture_output=True, text=True).stdout
        rows = []
        for line in out.splitlines():
            parts = line.split()
            if len(parts) >= 3:
                rows.append((int(parts[0]) / 1e9, parts[1], parts[2]))
        return rows

    # --- floors ---------------------------------------------------------------
    def apt_floor_script(self) -> str:
        """Docker's documented Debian install, against the lab's mirror of
        Docker's repository, then one pull of the payload and one run until
        its health check passes."""
        mirror = self.state["mirror_url"] + "/debian"
        registry = self.state["registry"]
        return " && ".join([
            "set -e",
            "export DEBIAN_FRONTEND=noninteractive",
            "sudo -E apt-get update -qq",
            "sudo -E apt-get install -y -qq ca-certificates curl >/dev/null",
            "sudo install -m 0755 -d /etc/apt/keyrings",
            f"sudo curl -fsSL {mirror}/gpg -o /etc/apt/keyrings/docker.asc",
            "sudo chmod a+r /etc/apt/keyrings/docker.asc",
            "printf 'Types: deb\\nURIs: %s\\nSuites: %s\\nComponents: stable\\nSigned-By: /etc/apt/keyrings/docker.asc\\n' "
            f"{mirror} \"$(. /etc/os-release && echo $VERSION_CODENAME)\" | sudo tee /etc/apt/sources.list.d/docker.sources >/dev/null",
            "sudo mkdir -p /etc/docker",
            # Not in Docker's recipe: the lab registry speaks plain HTTP.
            f"echo '{{\"insecure-registries\": [\"{registry}\"]}}' | sudo tee /etc/docker/daemon.json >/dev/null",
            "sudo -E apt-get update -qq",
            "sudo -E apt-get install -y -qq docker-ce docker-ce-cli containerd.io docker-buildx-plugin "
            "docker-compose-plugin >/dev/null",
            f"sudo docker pull -q {registry}/ros/payload:1.0 >/dev/null",
        ])

    def health_window(self) -> float:
        """Time from `docker run` of the payload to its health check passing
        (on the first robot, after the apt floor put Docker there)."""
        script = (
            f"sudo docker rm -f bench-health >/dev/null 2>&1; s=$(date +%s.%N); "
            f"sudo docker run -d --name bench-health {self.state['registry']}/ros/payload:1.0 >/dev/null; "
            "for i in $(seq 1 300); do "
            "[ \"$(sudo docker inspect -f '{{.State.Health.Status}}' bench-health)\" = healthy ] && break; sleep 0.2; done; "
            "e=$(date +%s.%N); sudo docker rm -f bench-health >/dev/null; echo \"$s $e\""
        )
        out = subprocess.run(self.ssh(self.robots[0], script), capture_output=True, text=True).stdout.split()
        return float(out[1]) - float(out[0])

    # --- the run ----------------------------------------------------------------
    def run(self, noop_runs: int = 3) -> dict:
        r: dict = {"robots": self.n}
        load = os.getloadavg()
        r["load_at_start"] = [round(x, 1) for x in load]
        log(f"N={self.n}: lab up (fresh hosts)")
        self.up(fresh=True)
        self.pyinfra("exec", "--", "true")  # warm caches, first host-key checks
        r["floor_ssh_true"] = min(self.parallel_ssh("true") for _ in range(3))
        r["floor_exec_true"] = min(self.pyinfra("exec", "--", "true")[0] for _ in range(3))
        log("apt floor (Docker's documented install + pull) on fresh hosts")
        r["floor_apt_pull"] = self.parallel_ssh(self.apt_floor_script())
        r["floor_health"] = self.health_window()
        r["floor_fresh"] = r["floor_apt_pull"] + r["floor_health"]

        log("fresh provision (hosts reset)")
        self.up(fresh=True)
        r["fresh"], code, counts = self.pyinfra("deploy.py", count=True)
        r["fresh_exit"] = code
        r["fresh_commands_per_host"] = max(c.get("commands", 0) for c in counts.values()) if counts else None

        noops, per_host = [], []
        for _ in range(noop_runs):
            seconds, _, counts = self.pyinfra("deploy.py", count=True)
            noops.append(seconds)
            per_host.append(max(c.get("commands", 0) for c in counts.values()))
        r["noop_runs"] = noops
        r["noop"] = statistics.median(noops)
        r["noop_commands_per_host"] = max(per_host)

        log("rollout of the whole fleet to 1.1 (canary 1, batch 50%)")
        started = time.monotonic()
        proc = subprocess.run([sys.executable, "-m", "engine", "rollout", "inventories/lab.py", "-y",
                               "--canary", "1", "--batch", "50%"], cwd=ROOT, env=self.env("1.1"),
                              capture_output=True, text=True)
        r["rollout"] = time.monotonic() - started
        r["rollout_exit"] = proc.returncode
        r["rollout_waves"] = sum(1 for line in proc.stderr.splitlines() if line.startswith("--> wave "))

        log("update all robots to 1.0")
        since = time.time()
        r["update_all"], r["update_all_exit"], _ = self.pyinfra("deploy.py", tag="1.0")
        r["downtime"] = {h: self.downtime(self.events(h, since)) for h in self.robots}
        log("update one robot to 1.1")
        r["update_one"], r["update_one_exit"], _ = self.pyinfra("deploy.py", "--limit", self.robots[0], tag="1.1")

        log("crash-looping release on one robot")
        since = time.time()
        r["crash_deploy"], r["crash_exit"], _ = self.pyinfra("deploy.py", "--limit", self.robots[0], tag="1.2-broken")
        r["crash_to_old_running"] = self.back_again(self.events(self.robots[0], since))
        r["crash_window"] = r["floor_health"] + 10
        self.ratios(r)
        return r

    @staticmethod
    def downtime(events) -> float | None:
        """Old container died -> new container started (seconds)."""
        died = [t for t, action, _ in events if action == "die"]
        started = [t for t, action, _ in events if action == "start"]
        if not died or not started:
            return None
        first_die = min(died)
        after = [t for t in started if t >= first_die]
        return (min(after) - first_die) if after else None

    @staticmethod
    def back_again(events) -> float | None:
        """The broken container starts -> the old release's container starts again."""
        starts = [(t, image) for t, action, image in events if action == "start"]
        broken = [t for t, image in starts if "1.2-broken" in image]
        if not broken:
            return None
        back = [t for t, image in starts if t > broken[0] and "1.2-broken" not in image]
        return (back[0] - broken[0]) if back else None

    @staticmethod
    def ratios(r: dict) -> None:
        def ratio(a, b):
            return round(a / b, 2) if a is not None and b else None

        downtimes = [d for d in r["downtime"].values() if d is not None]
        r["ratios"] = {
            "noop / pyinfra exec true": ratio(r["noop"], r["floor_exec_true"]),
            "noop / ssh true": ratio(r["noop"], r["floor_ssh_true"]),
            "fresh / (apt+pull+health)": ratio(r["fresh"], r["floor_fresh"]),
            "update all / update one": ratio(r["update_all"], r["update_one"]),
            "rollout / update all": ratio(r["rollout"], r["update_all"]),
            "rollout / (waves x update one)": ratio(r["rollout"], r["rollout_waves"] * r["update_one"]),
            "max downtime (s)": round(max(downtimes), 2) if downtimes else None,
            "crash -> old running / health window": ratio(r["crash_to_old_running"], r["floor_health"]),
            "crash deploy / (health window + 10 s)": ratio(r["crash_deploy"], r["crash_window"]),
        }


def measure(robots: int, prefix: str, keep: bool = False) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        bench = Bench(prefix, robots, Path(tmp))
        try:
            return bench.run()
        finally:
            if not keep:
                bench.down()
