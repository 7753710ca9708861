"""The fleet benchmark: every speed figure next to a floor measured in the
same run on the same simulated hosts.  Prints figures and returns them;
asserts nothing (timings stay out of the test suite).

For N robots (no laptop), on a lab of its own; every figure is the median
of ``runs`` samples (3 by default) with its spread, each sample taken after
waiting for the 1-minute load average to fall below 1.5 and marked with the
load it started at (tests/bench/hygiene.py); a floor and the figure it
bounds alternate on the same hosts in the same cache state:
  fresh    Docker's documented apt install of the five packages + one
           `docker pull` of the payload + the payload's health window, by
           hand over SSH, and the first deploy.py run, alternating on hosts
           reset before each (after one untimed floor run warms the apt
           cache and the registry for both)
  no-op    `pyinfra exec -- true` and a converged rerun, alternating (SSH
           commands per host counted), and N parallel `ssh true`
  update   all N robots to the other tag, then one robot there and back;
           each robot's update window: its old container's last moment
           running (FinishedAt) -> the new one's first (StartedAt), Docker's
           own clocks (tests/bench/window.py)
  rollout  robotfleet rollout of the whole fleet (canary 1, batch 50%)
  broken   one robot to a release that exits at once, and to one that
           runs but never turns healthy (tag 1.2-broken): Docker's verdict
           and the broken release's first start -> the old release running,
           with the image's health-check settings beside each
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from tests.bench import hygiene, window
from tests.bench.roundtrips import COUNTING
from tests.fixtures import pyinfra_argv

ROOT = Path(__file__).resolve().parents[2]
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

    def fleet_text(self, tag: str, command: str | None = None) -> str:
        """lab.yaml on ``tag``, for N robots; ``command``: robot1's payload_command."""
        text = (
            (ROOT / "inventories" / "lab.yaml")
            .read_text()
            .replace(ALL_TAG, f'payload_image: "@registry@/ros/payload:{tag}"', 1)
        )
        # lab.yaml declares robot1-3; the lab's inventory only has declared hosts.
        extra = "".join(f"    robot{i}: {{}}\n" for i in range(4, self.n + 1))
        text = text.replace("\nlaptops:", "\n" + extra + "\nlaptops:", 1) if extra else text
        if command:
            text = text.replace(
                "    robot1:\n      udev_sensors:",
                f"    robot1:\n      payload_command: {command}\n      udev_sensors:",
                1,
            )
        return text

    def fleet(self, tag: str, command: str | None = None) -> Path:
        path = self.workdir / f"lab-{tag}{'-command' if command else ''}.yaml"
        path.write_text(self.fleet_text(tag, command))
        return path

    def env(self, tag: str = "1.0", command: str | None = None) -> dict:
        return dict(
            os.environ,
            ROBOT_LAB_PREFIX=self.prefix,
            ROBOT_LAB_FLEET=str(self.fleet(tag, command)),
            PYINFRA_PROGRESS="off",
            ROBOT_ROLLOUT_DIR=str(self.workdir / "rollout"),
        )

    def ssh(self, host: str, command: str) -> list[str]:
        port = next(h["port"] for h in self.state["hosts"] if h["name"] == host)
        return [
            "ssh",
            "-q",
            "-i",
            self.state["ssh_key"],
            "-p",
            str(port),
            "-o",
            "BatchMode=yes",
            "-o",
            f"UserKnownHostsFile={self.state['known_hosts']}",
            "-o",
            "StrictHostKeyChecking=yes",
            f"{self.state['ssh_user']}@127.0.0.1",
            command,
        ]

    def parallel_ssh(self, command: str) -> float:
        started = time.monotonic()
        procs = [
            subprocess.Popen(self.ssh(h, command), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
            for h in self.robots
        ]
        errors = [p.communicate()[1] for p in procs if p.wait() != 0]
        seconds = time.monotonic() - started
        if errors:
            raise RuntimeError(f"ssh {command[:60]}...: {errors[0][-500:]}")
        return seconds

    def pyinfra(
        self, *args: str, tag: str = "1.0", count: bool = False, command: str | None = None
    ) -> tuple[float, int, dict]:
        report = self.workdir / "counts.json"
        prog = pyinfra_argv(str(report), setup=COUNTING) if count else pyinfra_argv()
        started = time.monotonic()
        proc = subprocess.run(
            [*prog, "-y", "inventories/lab.py", *args],
            cwd=ROOT,
            env=self.env(tag, command),
            capture_output=True,
            text=True,
        )
        seconds = time.monotonic() - started
        if proc.returncode != 0:
            log(f"pyinfra {' '.join(args)} exit {proc.returncode}: {proc.stderr[-800:]}")
        counts = json.loads(report.read_text()) if count and report.exists() else {}
        return seconds, proc.returncode, counts

    def sh(self, host: str):
        """A function running a shell command on ``host`` over SSH, returning its output."""

        def run(command: str) -> str:
            return subprocess.run(self.ssh(host, command), capture_output=True, text=True).stdout

        return run

    def watching(self, hosts: list[str], action) -> dict[str, window.Watch]:
        """What the payload did on each of ``hosts`` while ``action()`` ran
        (Docker's clocks on each robot, begun and ended in parallel)."""
        watches = {host: window.Watch(self.sh(host)) for host in hosts}
        with ThreadPoolExecutor(len(hosts)) as pool:
            list(pool.map(window.Watch.begin, watches.values()))
        try:
            action()
        finally:
            with ThreadPoolExecutor(len(hosts)) as pool:
                list(pool.map(window.Watch.end, watches.values()))
        return watches

    # --- floors ---------------------------------------------------------------
    def apt_floor_script(self) -> str:
        """Docker's documented Debian install, against the lab's mirror of
        Docker's repository, then one pull of the payload and one run until
        its health check passes."""
        mirror = self.state["mirror_url"] + "/debian"
        registry = self.state["registry"]
        return " && ".join(
            [
                "set -e",
                "export DEBIAN_FRONTEND=noninteractive",
                "sudo -E apt-get update -qq",
                "sudo -E apt-get install -y -qq ca-certificates curl >/dev/null",
                "sudo install -m 0755 -d /etc/apt/keyrings",
                f"sudo curl -fsSL {mirror}/gpg -o /etc/apt/keyrings/docker.asc",
                "sudo chmod a+r /etc/apt/keyrings/docker.asc",
                "printf 'Types: deb\\nURIs: %s\\nSuites: %s\\nComponents: stable\\nSigned-By: "
                "/etc/apt/keyrings/docker.asc\\n' "
                f'{mirror} "$(. /etc/os-release && echo $VERSION_CODENAME)" | sudo tee '
                "/etc/apt/sources.list.d/docker.sources >/dev/null",
                "sudo mkdir -p /etc/docker",
                # Not in Docker's recipe: the lab registry speaks plain HTTP.
                f'echo \'{{"insecure-registries": ["{registry}"]}}\' | sudo tee /etc/docker/daemon.json >/dev/null',
                "sudo -E apt-get update -qq",
                "sudo -E apt-get install -y -qq docker-ce docker-ce-cli containerd.io docker-buildx-plugin "
                "docker-compose-plugin >/dev/null",
                f"sudo docker pull -q {registry}/ros/payload:1.0 >/dev/null",
            ]
        )

    def health_window(self) -> float:
        """Time from `docker run` of the payload to its health check passing
        (on the first robot, after the apt floor put Docker there)."""
        script = (
            f"sudo docker rm -f bench-health >/dev/null 2>&1; s=$(date +%s.%N); "
            f"sudo docker run -d --name bench-health {self.state['registry']}/ros/payload:1.0 >/dev/null; "
            "for i in $(seq 1 300); do "
            "[ \"$(sudo docker inspect -f '{{.State.Health.Status}}' bench-health)\" = healthy ] && break; sleep 0.2; "
            "done; "
            'e=$(date +%s.%N); sudo docker rm -f bench-health >/dev/null; echo "$s $e"'
        )
        out = subprocess.run(self.ssh(self.robots[0], script), capture_output=True, text=True).stdout.split()
        return float(out[1]) - float(out[0])

    # --- the run ----------------------------------------------------------------
    def timed(self, name: str, run) -> float:
        """Time ``run()`` as one sample of figure ``name``, after waiting for
        an idle machine (tests/bench/hygiene.py); the load goes with it."""
        figure = self.figures.setdefault(name, hygiene.Figure())
        load, idle = hygiene.wait(f"N={self.n} {name}", first=not figure.samples)
        started = time.monotonic()
        run()
        return figure.add(time.monotonic() - started, load, idle)

    def deploy(self, *args: str, tag: str = "1.0", count: bool = False, command: str | None = None) -> tuple[int, dict]:
        _, code, counts = self.pyinfra("deploy.py", *args, tag=tag, count=count, command=command)
        return code, counts

    def fresh_pairs(self, r: dict, runs: int) -> None:
        """The floor (Docker's apt install + one pull, by hand) and the fresh
        provision, alternating on reset hosts, after one untimed floor run
        so both meet the same (warm) apt cache and registry."""
        log("warm-up: one untimed apt floor on fresh hosts (apt cache, registry)")
        self.parallel_ssh(self.apt_floor_script())
        r["fresh_exit"], r["fresh_commands_per_host"] = [], []
        for index in range(runs):
            order = ("floor", "fresh") if index % 2 == 0 else ("fresh", "floor")
            for kind in order:
                self.up(fresh=True)
                if kind == "floor":
                    log(f"apt floor {index + 1}/{runs}")
                    self.timed("floor_apt_pull", lambda: self.parallel_ssh(self.apt_floor_script()))
                    health = self.figures.setdefault("floor_health", hygiene.Figure())
                    load, idle = hygiene.wait(f"N={self.n} floor_health", first=not health.samples)
                    health.add(self.health_window(), load, idle)
                else:
                    log(f"fresh provision {index + 1}/{runs}")
                    result = {}
                    self.timed("fresh", lambda: result.update(zip(("code", "counts"), self.deploy(count=True))))
                    r["fresh_exit"].append(result["code"])
                    r["fresh_commands_per_host"].append(
                        max(c.get("commands", 0) for c in result["counts"].values()) if result["counts"] else None
                    )
        if order[-1] == "floor":  # leave the hosts provisioned
            self.up(fresh=True)
            self.deploy()

    def noop_pairs(self, r: dict, runs: int) -> None:
        """`pyinfra exec -- true` and the no-op rerun, alternating on the same
        converged hosts, with N parallel `ssh true` beside them."""
        per_host = []
        for index in range(runs):
            order = ("exec", "noop") if index % 2 == 0 else ("noop", "exec")
            for kind in order:
                if kind == "exec":
                    self.timed("floor_exec_true", lambda: self.pyinfra("exec", "--", "true"))
                else:
                    found = {}
                    self.timed("noop", lambda: found.update(counts=self.deploy(count=True)[1]))
                    per_host.append(max(c.get("commands", 0) for c in found["counts"].values()))
            self.timed("floor_ssh_true", lambda: self.parallel_ssh("true"))
        r["noop_commands_per_host"] = max(per_host)

    def update_cycles(self, r: dict, runs: int) -> None:
        """Each cycle: every robot to the other tag (all N change), then
        robot1 back and forth alone (one changes each time); every update's
        window on every robot that changed."""
        tags = ("1.1", "1.0")
        r["window"], r["update_exits"] = {}, []
        for index in range(runs):
            new, old = tags[index % 2], tags[(index + 1) % 2]
            log(f"update all robots to {new} ({index + 1}/{runs})")
            watches = self.watching(
                self.robots, lambda: self.timed("update_all", lambda: r["update_exits"].append(self.deploy(tag=new)[0]))
            )
            self.windows("window_all", watches, "update_all", r["window"])
            for tag in (old, new):
                log(f"update one robot to {tag}")
                watches = self.watching(
                    self.robots[:1],
                    lambda: self.timed(
                        "update_one",
                        lambda: r["update_exits"].append(self.deploy("--limit", self.robots[0], tag=tag)[0]),
                    ),
                )
                self.windows("window_one", watches, "update_one")

    def windows(self, name: str, watches: dict, taken_with: str, per_robot: dict | None = None) -> None:
        """Each robot's update window as a sample of figure ``name``, with the
        load of the update's own sample (``taken_with``)."""
        update = self.figures[taken_with]
        for host, watch in watches.items():
            value = watch.window()
            if value is None:
                log(f"{host}: no update window found (was its payload replaced?)")
                continue
            self.figures.setdefault(name, hygiene.Figure()).add(value, update.loads[-1], update.idles[-1])
            if per_robot is not None:
                per_robot.setdefault(host, []).append(round(value, 3))

    def rollouts(self, r: dict, runs: int) -> None:
        r["rollout_exit"], r["rollout_waves"] = [], None
        for _ in range(runs):
            tag = "1.0" if self.tag == "1.1" else "1.1"  # every robot changes
            log(f"rollout of the whole fleet to {tag} (canary 1, batch 50%)")
            # A rollout to a target it completed before resumes, finding nothing
            # to do: each sample starts without the earlier ones' state.
            shutil.rmtree(self.workdir / "rollout", ignore_errors=True)
            proc = {}
            self.timed(
                "rollout",
                lambda: proc.update(
                    p=subprocess.run(
                        [
                            sys.executable,
                            "-m",
                            "robotfleet",
                            "rollout",
                            "inventories/lab.py",
                            "-y",
                            "--canary",
                            "1",
                            "--batch",
                            "50%",
                        ],
                        cwd=ROOT,
                        env=self.env(tag),
                        capture_output=True,
                        text=True,
                    )
                ),
            )
            self.tag = tag
            r["rollout_exit"].append(proc["p"].returncode)
            waves = sum(1 for line in proc["p"].stderr.splitlines() if line.startswith("--> wave "))
            r["rollout_waves"] = max(r["rollout_waves"] or 0, waves)

    def broken(self, r: dict, runs: int) -> None:
        """robot1 to each kind of broken release (window.BROKEN): the deploy
        until it failed, and from Docker's verdict and from the broken
        release's first start to the old release running again."""
        r["broken_exit"], r["broken_settings"] = [], {}
        host = self.robots[0]
        for kind, (tag, command) in window.BROKEN.items():
            key = "exit" if command else "unhealthy"
            for index in range(runs):
                log(f"broken release on one robot, {kind} ({index + 1}/{runs})")
                found = {}
                watches = self.watching(
                    [host],
                    lambda: self.timed(
                        f"broken_{key}_deploy",
                        lambda: found.update(code=self.deploy("--limit", host, tag=tag, command=command)[0]),
                    ),
                )
                r["broken_exit"].append(found["code"])
                figure = self.figures[f"broken_{key}_deploy"]
                seen = watches[host].broken() or {}
                for part, name in (("verdict_to_old_running", "verdict"), ("first_start_to_old_running", "first")):
                    if part in seen:
                        self.figures.setdefault(f"broken_{key}_{name}", hygiene.Figure()).add(
                            seen[part], figure.loads[-1], figure.idles[-1]
                        )
                r["broken_settings"][kind] = f"verdict: {seen.get('verdict', 'none seen')}; " + window.health_settings(
                    self.sh(host), tag, self.fleet_text(tag, command)
                )

    def run(self, runs: int = 3, fresh: bool = True, updates: bool = True) -> dict:
        self.figures: dict[str, hygiene.Figure] = {}
        r: dict = {"robots": self.n, "runs": runs}
        r["load_at_start"] = [round(x, 2) for x in os.getloadavg()]
        log(f"N={self.n}: lab up (fresh hosts)")
        self.up(fresh=True)
        self.pyinfra("exec", "--", "true")  # warm caches, first host-key checks
        if fresh:
            self.fresh_pairs(r, runs)
        else:
            log("first deploy (untimed)")
            self.deploy()
        self.noop_pairs(r, runs)
        if updates:
            self.update_cycles(r, runs)
            self.tag = ("1.1", "1.0")[(runs - 1) % 2]
            self.rollouts(r, runs)
            self.broken(r, runs)
        r["figures"] = {name: figure.as_dict() for name, figure in self.figures.items()}
        if "floor_apt_pull" in self.figures and "floor_health" in self.figures:
            r["figures"]["floor_fresh"] = {
                **hygiene.Figure(
                    [
                        a + b
                        for a, b in zip(self.figures["floor_apt_pull"].samples, self.figures["floor_health"].samples)
                    ],
                    [
                        max(a, b)
                        for a, b in zip(self.figures["floor_apt_pull"].loads, self.figures["floor_health"].loads)
                    ],
                    [a and b for a, b in zip(self.figures["floor_apt_pull"].idles, self.figures["floor_health"].idles)],
                ).as_dict()
            }
        r["load_at_end"] = [round(x, 2) for x in os.getloadavg()]
        self.ratios(r)
        return r

    @staticmethod
    def ratios(r: dict) -> None:
        figures = r["figures"]

        def median(name):
            return (figures.get(name) or {}).get("median")

        def ratio(a, b):
            a, b = median(a), median(b)
            return round(a / b, 2) if a is not None and b else None

        windows = [w for values in r.get("window", {}).values() for w in values]
        waves = r.get("rollout_waves")
        one = median("update_one")
        r["ratios"] = {
            "noop / pyinfra exec true": ratio("noop", "floor_exec_true"),
            "noop / ssh true": ratio("noop", "floor_ssh_true"),
            "fresh / (apt+pull+health)": ratio("fresh", "floor_fresh"),
            "update all / update one": ratio("update_all", "update_one"),
            "rollout / update all": ratio("rollout", "update_all"),
            "rollout / (waves x update one)": round(median("rollout") / (waves * one), 2)
            if median("rollout") and waves and one
            else None,
            "max update window (s)": round(max(windows), 2) if windows else None,
            "exits at once: exit -> old running (s)": median("broken_exit_verdict"),
            "never healthy: unhealthy -> old running (s)": median("broken_unhealthy_verdict"),
        }
        # Which ratio had every sample of both its figures taken idle.
        pairs = {
            "noop / pyinfra exec true": ("noop", "floor_exec_true"),
            "noop / ssh true": ("noop", "floor_ssh_true"),
            "fresh / (apt+pull+health)": ("fresh", "floor_fresh"),
            "update all / update one": ("update_all", "update_one"),
            "rollout / update all": ("rollout", "update_all"),
            "max update window (s)": ("window_all", "window_all"),
            "exits at once: exit -> old running (s)": ("broken_exit_verdict", "broken_exit_verdict"),
            "never healthy: unhealthy -> old running (s)": ("broken_unhealthy_verdict", "broken_unhealthy_verdict"),
        }
        r["ratios_idle"] = {
            key: all((figures.get(name) or {}).get("idle", False) for name in names) for key, names in pairs.items()
        }
        for key in ("exits at once: exit -> old running (s)", "never healthy: unhealthy -> old running (s)"):
            if r["ratios"][key] is not None:
                r["ratios"][key] = round(r["ratios"][key], 2)


def measure(
    robots: int, prefix: str, keep: bool = False, runs: int = 3, fresh: bool = True, updates: bool = True
) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        bench = Bench(prefix, robots, Path(tmp))
        try:
            return bench.run(runs=runs, fresh=fresh, updates=updates)
        finally:
            if not keep:
                bench.down()
