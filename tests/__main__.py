"""The test command (README, .ci/run): the three layers, the end-to-end one
on several labs at once, beside the other two.

    .venv/bin/python -m tests [PYTEST OPTIONS]

The end-to-end layer spends most of its time waiting on its simulated
hosts (their apt, Docker and systemd), and the unit and integration layers
need no host, so they run at the same time: one pytest process for unit and
integration, in two processes (the second ends with the end-to-end modules
that need no lab: groups.WITH_UNIT),
one per end-to-end lab group (tests/e2e/groups.py: each group
on its own lab, prefix ``<ROBOT_LAB_E2E_PREFIX or e2e>-<group>``, its modules
one after the other).  The first group's output streams here; each other
group's, then unit and integration's, follow whole when done, each headed
with its wall time and CPU.  The exit code is pytest's for the first layer that
failed, unit and integration first, then the groups in order (0 when all
passed; a process whose tests the options leave out does not count).
Options are handed to every process (e.g. -x, -k, -p no:cacheprovider).
Every process runs with at most 1,024 open files (OPEN_FILES), as on a
fresh machine, whatever this shell's limit is.

One layer alone: .venv/bin/python -m pytest tests/unit (or tests/integration,
tests/e2e: every end-to-end module on one lab); all three one after the
other: .venv/bin/python -m pytest.
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from tests.e2e import groups

ROOT = Path(__file__).resolve().parent.parent
E2E_PREFIX = "ROBOT_LAB_E2E_PREFIX"


class Layer:
    """One pytest process: its output streamed, or kept until it is done."""

    def __init__(
        self, label: str, what: str, paths: list[str], options: list[str], env: dict | None = None, stream: bool = False
    ) -> None:
        self.label, self.name, self.started, self.ended = label, f"{label} ({what})", time.monotonic(), None
        self.cpu = 0.0
        if stream:
            print(f"===== {self.name}: streamed here; the others follow when done =====", flush=True)
        self.log = None if stream else tempfile.TemporaryFile(mode="w+", prefix="tests-")
        self.process = subprocess.Popen(
            [sys.executable, "-m", "pytest", *paths, *options],
            cwd=ROOT,
            env=env,
            stdout=self.log,
            stderr=subprocess.STDOUT if self.log else None,
            text=True,
        )

    def wait(self) -> int:
        self.reap(0)
        return self.process.returncode

    def poll(self) -> None:
        self.reap(os.WNOHANG)

    def reap(self, flags: int) -> None:
        """Waits with wait4: its CPU (user and system, with every process it
        waited for: pyinfra, the CLIs; not the labs' containers) is the
        layer's figure in the summary."""
        if self.ended is not None:
            return
        pid, status, usage = os.wait4(self.process.pid, flags)
        if pid:
            self.process.returncode = os.waitstatus_to_exitcode(status)
            self.cpu, self.ended = usage.ru_utime + usage.ru_stime, time.monotonic()

    def show(self) -> None:
        code = self.wait()
        took = f"{duration(self.ended - self.started)}, {self.cpu:.0f} s of CPU"
        print(f"\n===== {self.name}: exit {code} in {took} =====", flush=True)
        if self.log is not None:
            self.log.seek(0)
            sys.stdout.write(self.log.read())
            sys.stdout.flush()
            self.log.close()


def duration(seconds: float) -> str:
    minutes, seconds = divmod(round(seconds), 60)
    return f"{minutes} min {seconds} s"


def local_layers(options: list[str]) -> list[Layer]:
    """Unit and integration in two processes (they spend much of their time
    waiting on the processes they start, and pytest-xdist's workers do not
    run under gevent's patches): the unit layer and every other integration
    module, then the rest of integration and the end-to-end modules that need
    no lab (groups.WITH_UNIT)."""
    base = os.environ.get(E2E_PREFIX, "e2e")
    first, second = local_paths(groups.plan(groups.modules()))
    layers = []
    for index, (paths, prefix) in enumerate([(first, f"{base}-unit"), (second, f"{base}-unit2")], start=1):
        modules = sum(path.startswith("tests/integration/") for path in paths)
        what = ", ".join(
            [p for p in paths if not p.startswith("tests/integration/")] + [f"{modules} integration modules"]
        )
        env = dict(os.environ, **{E2E_PREFIX: prefix})
        layers.append(Layer(f"unit and integration ({index})", what, paths, options, env))
    return layers


def local_paths(planned: dict[str, list[str]], root: Path = ROOT) -> tuple[list[str], list[str]]:
    integration = sorted(path.relative_to(root).as_posix() for path in (root / "tests/integration").glob("test_*.py"))
    first = ["tests/unit", *integration[0::2]]
    second = [*integration[1::2], *(f"tests/e2e/{module}" for module in planned.get(groups.WITH_UNIT, []))]
    return first, second


def e2e_layers(options: list[str]) -> list[Layer]:
    base = os.environ.get(E2E_PREFIX, "e2e")
    planned = groups.plan(groups.modules())
    planned.pop(groups.WITH_UNIT, None)
    layers = []
    for index, (group, modules) in enumerate(planned.items()):
        env = dict(os.environ, **{E2E_PREFIX: f"{base}-{group}"})
        layers.append(
            Layer(
                f"end to end, lab group {group}",
                f"lab {base}-{group}: {', '.join(modules)}",
                [f"tests/e2e/{module}" for module in modules],
                options,
                env,
                stream=index == 0,
            )
        )
    return layers


# The usual soft limit of open files on a fresh machine: the layers run
# under it wherever they run, so a descriptor leak fails here as on CI.
OPEN_FILES = 1024


def usual_open_file_limit() -> None:
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft == resource.RLIM_INFINITY or soft > OPEN_FILES:
        resource.setrlimit(resource.RLIMIT_NOFILE, (OPEN_FILES, hard))


def machine_seconds() -> tuple[float, float]:
    """The machine's core-seconds busy and idle (with iowait) since boot,
    from /proc/stat: what the labs' containers and Docker spend counts too."""
    try:
        with open("/proc/stat") as stat:
            fields = [int(x) for x in stat.readline().split()[1:8]]
    except OSError:
        return 0.0, 0.0
    tick, idle = os.sysconf("SC_CLK_TCK"), fields[3] + fields[4]
    return (sum(fields) - idle) / tick, idle / tick


def main(argv: list[str]) -> int:
    started, (busy0, idle0) = time.monotonic(), machine_seconds()
    usual_open_file_limit()
    local = local_layers(argv)
    e2e = e2e_layers(argv)
    every = [*local, *e2e]
    try:
        while True:  # each end noted as it comes, so each wall time is its own
            for layer in every:
                layer.poll()
            if all(layer.ended is not None for layer in every):
                break
            time.sleep(1)
        for layer in [*e2e, *local]:
            layer.show()
    except KeyboardInterrupt:
        for layer in every:
            layer.process.terminate()
        for layer in every:
            layer.wait()
        raise
    codes = [layer.wait() for layer in every]
    load = " ".join(f"{value:.2f}" for value in os.getloadavg())
    exits = ", ".join(f"{layer.label} exit {code}" for layer, code in zip(every, codes))
    cpu = sum(layer.cpu for layer in every)
    busy, idle = (now - then for now, then in zip(machine_seconds(), (busy0, idle0)))
    print(
        f"\n===== tests: {exits}; {duration(time.monotonic() - started)} in all, {cpu:.0f} s of CPU in the layers'"
        f" processes; the machine {busy:.0f} core-seconds busy, {idle:.0f} idle (load average at the end {load}) =====",
        flush=True,
    )
    return exit_code(codes)


def exit_code(codes: list[int]) -> int:
    """The first failing process's code, in order; 0 when all passed.  5 is
    pytest's "no tests collected" (options that select none of a process's
    tests): it counts only when every process says it."""
    ran = [code for code in codes if code != 5] or [5]
    return next((code for code in ran if code), 0)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
