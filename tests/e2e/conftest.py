"""The simulated fleet for end-to-end tests: one lab per session, provisioned
over SSH with the real pyinfra CLI.  In CI a missing engine is a failure."""

from __future__ import annotations

import json
import os
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.fixtures import ROOT, pyinfra  # ROOT: the e2e modules import it from here too

PREFIX = os.environ.get("ROBOT_LAB_E2E_PREFIX", "e2e")
E2E_DIR = Path(__file__).resolve().parent


ARM64_MODULE = "test_arm64.py"
PULL_MODULE = "test_pull.py"
# Pull mode on a robot with no network, and prefetch (tests/e2e/test_pull_media.py).
PULL_MEDIA_MODULE = "test_pull_media.py"
# Releases from a static HTTPS mirror, reports to gitolite (tests/e2e/test_pull_https.py).
PULL_HTTPS_MODULE = "test_pull_https.py"
PULL_MODULES = (PULL_MODULE, PULL_MEDIA_MODULE, PULL_HTTPS_MODULE)
# Modules that never use the laptop: a session of only these starts none (its
# first run, idle engine and payload are CPU the other labs need).
WITHOUT_LAPTOP = PULL_MODULES
# Bad links (tests/e2e/test_links.py): in a session with it, the first run
# reaches SLOW_ROBOT over a 300 ms round trip (150 ms each way).
LINKS_MODULE = "test_links.py"
SLOW_ROBOT, SLOW_DELAY = "robot3", 0.150


def pytest_collection_modifyitems(items):
    for item in items:
        if "/e2e/" in str(item.fspath):
            item.add_marker(pytest.mark.e2e)
    # The emulated arm64 robot is the slowest host to build: its module runs
    # after the others, and its image is built (when its recipe changed) in
    # the background while they run (see `lab`; another lab building the same
    # tag is waited for: tests/lab/machinelock.py).  Its run expects robot1 as
    # the session's first run left it.
    # The pull module turns the robots' sshd off while it runs (it turns it
    # back on at its end) and leaves them on its own releases: it runs last,
    # then the media module (it takes robot3 into its own pull fleet and
    # removes that fleet's agent and releases at its end).
    items.sort(
        key=lambda item: (
            item.fspath.basename in PULL_MODULES,
            item.fspath.basename == PULL_MEDIA_MODULE,
            item.fspath.basename == ARM64_MODULE,
        )
    )


class Background:
    """A lab step run in a thread beside the tests; ``wait`` re-raises its error."""

    def __init__(self, name: str, target) -> None:
        self.name, self.error = name, None
        self.started = time.monotonic()

        def run() -> None:
            try:
                target()
            except BaseException as error:  # re-raised in the test that needs it
                self.error = error

        self.thread = threading.Thread(target=run, name=name, daemon=True)
        self.thread.start()

    def wait(self) -> None:
        waited = time.monotonic()
        self.thread.join()
        phase(f"{self.name} (in the background; waited {time.monotonic() - waited:.1f} s for it)", self.started)
        if self.error is not None:
            raise self.error


BACKGROUND: dict[str, Background] = {}


@dataclass
class Run:
    returncode: int
    output: str
    results: dict | None
    seconds: float

    @property
    def changed_hosts(self) -> set[str]:
        return {h for op in (self.results or {}).get("operations", []) for h in op["success"]}

    @property
    def failed_hosts(self) -> set[str]:
        return {h for op in (self.results or {}).get("operations", []) for h in op["error"]}

    def changes(self, host: str) -> list[str]:
        return [op["name"] for op in (self.results or {}).get("operations", []) if host in op["success"]]


PHASES: list[str] = []


def phase(name: str, started: float) -> None:
    line = f"{name}: {time.monotonic() - started:.1f} s"
    PHASES.append(line)
    print(f"\n[e2e] {line}", flush=True)


# {module: [wall seconds, CPU seconds]}, each test's setup, call and teardown counted (docs/development.md).
MODULES: dict[str, list[float]] = {}
# Of each of the lab's containers: [the last CPU seconds read, the CPU seconds counted] (a restart zeroes its cgroup).
CONTAINER_CPU: dict[str, list[float]] = {}


def cpu_seconds() -> float:
    """CPU time of this process, its children and its labs' containers
    (prefix PREFIX and PREFIX-*; a removed container counts until its last reading)."""
    import resource

    from tests.lab.engine import LabError, client

    used = sum(
        getattr(resource.getrusage(who), field)
        for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)
        for field in ("ru_utime", "ru_stime")
    )
    try:  # sparse: the list's own answer, not one more request per container
        containers = client().containers.list(sparse=True, filters={"label": "robot-lab.prefix"})
    except LabError:  # no engine: the lab fixture says so
        containers = []
    for container in containers:
        if any(name.lstrip("/").startswith(f"{PREFIX}-") for name in container.attrs.get("Names") or []):
            for path, scale in (
                (f"/sys/fs/cgroup/cpuacct/docker/{container.id}/cpuacct.usage", 1e-9),
                (f"/sys/fs/cgroup/system.slice/docker-{container.id}.scope/cpu.stat", 1e-6),
            ):
                try:
                    text = Path(path).read_text()
                except OSError:
                    continue
                seconds = scale * int(text.split()[1] if "usage_usec" in text else text)
                last, counted = CONTAINER_CPU.get(container.id, [0.0, 0.0])
                CONTAINER_CPU[container.id] = [seconds, counted + (seconds - last if seconds >= last else seconds)]
                break
    return used + sum(counted for _, counted in CONTAINER_CPU.values())


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item):
    if E2E_DIR not in Path(str(item.fspath)).resolve().parents:  # a unit or integration test in the same session
        yield
        return
    wall, cpu = time.monotonic(), cpu_seconds()
    yield
    spent = MODULES.setdefault(item.fspath.basename, [0.0, 0.0])
    spent[0] += time.monotonic() - wall
    spent[1] += cpu_seconds() - cpu


def pytest_terminal_summary(terminalreporter):
    """The time of each end-to-end phase and module, also when output is captured."""
    if PHASES:
        terminalreporter.section("end-to-end phases")
        for line in PHASES:
            terminalreporter.write_line(line)
    if MODULES:
        terminalreporter.section(f"end-to-end modules on lab {PREFIX} (wall; CPU of pytest, its children, the lab)")
        for module, (wall, cpu) in MODULES.items():
            terminalreporter.write_line(f"{module:<28} {wall:7.1f} s wall {cpu:7.1f} s CPU")
        load = " ".join(f"{value:.2f}" for value in os.getloadavg())
        terminalreporter.write_line(
            f"{'all':<28} {sum(w for w, _ in MODULES.values()):7.1f} s wall "
            f"{sum(c for _, c in MODULES.values()):7.1f} s CPU (load average {load})"
        )


def wait_for(predicate, seconds: float, what: str, interval: float = 0.5):
    """Poll ``predicate`` until it is true; an AssertionError from it (a host
    still booting, a container not there yet) counts as "not yet"."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        try:
            if predicate():
                return
        except AssertionError:
            pass
        time.sleep(interval)
    raise AssertionError(f"timed out after {seconds} s waiting for {what}")


class Lab:
    def __init__(self, state: dict):
        self.state = state
        self.prefix = state["prefix"]
        self.hosts = [h["name"] for h in state["hosts"]]
        self.robots = [h["name"] for h in state["hosts"] if h["group"] == "robots"]
        self.laptops = [h["name"] for h in state["hosts"] if h["group"] == "laptops"]

    def sh(self, host: str, command: str, user: str | None = None) -> tuple[int, str]:
        from tests.lab.state import exec_in

        return exec_in(self.prefix, host, command, user=user)

    def ok(self, host: str, command: str, user: str | None = None) -> str:
        code, output = self.sh(host, command, user)
        assert code == 0, f"{host}: {command}: exit {code}: {output}"
        return output

    def payload(self, host: str) -> dict:
        """`docker inspect` of the host's one payload container."""
        ids = self.ok(host, "docker ps -q --filter label=com.docker.compose.project=robot-payload").split()
        assert len(ids) == 1, f"{host}: expected one payload container, got {ids}"
        return json.loads(self.ok(host, f"docker inspect {ids[0]}"))[0]

    def version(self, host: str) -> str:
        """The test payload's version label (1.0, 1.1, ...) the host runs."""
        return self.payload(host)["Config"]["Labels"]["org.opencontainers.image.version"]

    def record(self, host: str, link: str = "current") -> dict:
        return json.loads(self.ok(host, f"cat /var/lib/robot-payload/{link}/record.json"))

    def provision(
        self, *args: str, fleet: Path | None = None, script: str = "deploy.py", label: str = "", env: dict | None = None
    ) -> Run:
        env = dict(os.environ, ROBOT_LAB_PREFIX=self.prefix, PYINFRA_PROGRESS="off", **(env or {}))
        if fleet:
            env["ROBOT_LAB_FLEET"] = str(fleet)
        started = time.monotonic()
        proc = pyinfra("-y", "--json", "inventories/lab.py", script, *args, env=env, timeout=1500)
        seconds = time.monotonic() - started
        phase(f"pyinfra {script} {label} (exit {proc.returncode})", started)
        try:
            results = json.loads(proc.stdout)["results"]
        except (ValueError, KeyError, TypeError):
            results = None
        return Run(proc.returncode, proc.stderr + proc.stdout, results, seconds)

    def fleet_with(self, tmp_path: Path, **replacements: str) -> Path:
        """A copy of inventories/lab.yaml with text replaced (e.g. one tag)."""
        text = (ROOT / "inventories" / "lab.yaml").read_text()
        for old, new in replacements.items():
            assert old in text, old
            text = text.replace(old, new, 1)
        path = tmp_path / "lab.yaml"
        path.write_text(text)
        return path


@pytest.fixture(scope="session", autouse=True)
def arm64_image(request):
    """The arm64 host image (when its recipe changed) built in the background
    from the session's first test on, when the arm64 module is in the session."""
    if any(item.fspath.basename == ARM64_MODULE for item in request.session.items):
        from tests.lab import hostimage, hosts

        def build() -> None:
            favour_this_thread()
            hostimage.ensure_host_image(hosts.client(), "arm64")

        BACKGROUND["arm64 host image"] = Background("arm64 host image", build)


ROS_MODULE = "test_ros.py"


@pytest.fixture(scope="session", autouse=True)
def ros_image(request):
    """The real ROS image (tests/lab/ros_images.py; when its recipe changed)
    built in the background from the session's first test on, when the ROS
    module is in the session."""
    if any(item.fspath.basename == ROS_MODULE for item in request.session.items):
        from tests.lab import ros_images

        BACKGROUND["ROS image"] = Background("ROS image", ros_images.build)


# The arm64 image's build (its dpkg and maintainer scripts under emulation,
# one core for 8 minutes; 12-15 with debootstrap) is the test command's longest path on a machine
# that has not built it: beside the other labs and unit tests it got half a
# core and took 42 minutes on CI.  Linux keeps a nice value per thread and
# its children inherit it, so the build's thread and the chroot under it get
# the larger share; the other processes keep the rest.  Without the right
# to raise priority (not root) it runs as before.
BUILD_NICE = -10


def favour_this_thread() -> None:
    try:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), BUILD_NICE)
    except OSError:
        pass


@pytest.fixture(scope="session")
def stock_machine():
    """A stock Debian 13 container with this checkout set up (tests/e2e/stock_machine.py)."""
    from tests.e2e import stock_machine as machine

    started = time.monotonic()
    for made in machine.started(f"{PREFIX}-stock"):
        phase("stock Debian 13 container: .ci/setup --python", started)
        yield made


@pytest.fixture(scope="session")
def lab(request):
    from tests.lab import hosts

    started = time.monotonic()
    hosts.down(PREFIX)  # fresh hosts every session, whatever an earlier run left
    # The git server pull mode needs, only when one of its modules runs (tests/e2e/test_pull*.py).
    modules = {item.fspath.basename for item in request.session.items}
    git_server = bool(modules & set(PULL_MODULES))
    laptops = 0 if modules <= set(WITHOUT_LAPTOP) else 1
    state = hosts.up(PREFIX, robots=3, laptops=laptops, git_server=git_server)
    phase("lab up (images, services, hosts)", started)
    yield Lab(state)
    if not os.environ.get("ROBOT_LAB_KEEP"):
        hosts.down(PREFIX)


def one_robot_lab(name: str):
    """A lab of one robot beside the session's, prefix ``<PREFIX>-<name>``:
    for a module that changes the robot's SSH side (its host keys, its
    sshd's certificate) or needs a robot nobody provisioned.  The session's
    lab is never taken down or changed by it, whatever order modules run in.
    A generator for a module-scoped fixture."""
    from tests.lab import hosts

    prefix = f"{PREFIX}-{name}"
    started = time.monotonic()
    hosts.down(prefix)
    state = hosts.up(prefix, robots=1, laptops=0)
    phase(f"lab {prefix} up (one robot)", started)
    yield Lab(state)
    if not os.environ.get("ROBOT_LAB_KEEP"):
        hosts.down(prefix)


@pytest.fixture(scope="session")
def slow_link(lab):
    """The bad link the session's first run reaches SLOW_ROBOT through (tests/lab/linkproxy.py)."""
    from tests.lab import linkproxy

    port = next(h["port"] for h in lab.state["hosts"] if h["name"] == SLOW_ROBOT)
    with linkproxy.Link(port, delay=SLOW_DELAY) as link:
        yield link


@pytest.fixture(scope="session")
def first_run(lab, request):
    """The fresh provisioning of the whole lab, shared by every e2e module
    (with the links module in the session, SLOW_ROBOT over its slow link)."""
    env = None
    if any(item.fspath.basename == LINKS_MODULE for item in request.session.items):
        from tests.lab import linkproxy

        env = linkproxy.through(lab.state, {SLOW_ROBOT: request.getfixturevalue("slow_link")})
    run = lab.provision(label="(fresh fleet)", env=env)
    assert run.returncode == 0, run.output[-6000:]
    return run
