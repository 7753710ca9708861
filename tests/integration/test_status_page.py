"""The page of the fleet (issue 54, item 11): ``robotfleet status --html
FILE``, rendered by a real browser (Debian's headless chromium).  One status
run prints --json and writes the page, from robots on 127.0.0.1 (real SSH
servers answering the status command, one closed port), pull robots' reports
on a bare fleet remote (as robots push them), and a rollout's state where
``robotfleet rollout`` keeps it; then what the browser rendered (its DOM)
is compared with the JSON: the counts, each host's health, its rollout
place, the waves, each pull robot's report time and age, when it was taken.
Robots' text carries HTML (a forged table row, an image with a handler):
on the page it is text, never elements."""

from __future__ import annotations

import datetime
import json
import shutil
import struct
import subprocess
import time
from html.parser import HTMLParser
from pathlib import Path

import paramiko
import pytest

from robotfleet.commands import rollout_plan
from robotfleet.pull.protocol import reports
from robotfleet.pull.robot import transport
from tests.integration import sshserver
from tests.integration.operator_side import fleet, run
from tests.integration.pullworld import pullkit_key
from tests.integration.statusrobots import IMAGE, report, robot

pytestmark = pytest.mark.integration

UTC = datetime.timezone.utc
KEY = " ".join(pullkit_key().split()[:2])  # a pull robot's own key
FORGED_ROW = '</td></tr><tr data-host="forged" data-health="healthy"><td>'
HANDLER = '<img src=x onerror="document.title=1">'
BOLD = '<b id="injected">bold</b>'
# Each host's health as the fixtures make it, beside what status --json says of it.
EXPECTED = {
    "robot1": "healthy",
    "robot2": "drifted",  # its container is unhealthy
    "robot3": "drifted",  # its health is a robot's markup, not "healthy"
    "robot4": "unreachable",  # a closed port
    "robot5": "healthy",  # a pull robot's fresh report
    "robot6": "failed",  # a pull robot that failed its release
    "robot7": "unreachable",  # a pull robot without a report
}
REPORT_AGE = datetime.timedelta(minutes=7)


def chromium() -> str:
    found = shutil.which("chromium")
    if not found:
        pytest.fail("chromium is not installed: .ci/setup installs it (Debian's chromium)")
    return found


def browse(page: Path, *how: str) -> subprocess.CompletedProcess:
    """Headless chromium on the page, with no name resolving (nothing may be fetched)."""
    profile = page.parent / "chromium-profile"
    return subprocess.run(
        [
            chromium(),
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--no-first-run",
            f"--user-data-dir={profile}",
            "--host-resolver-rules=MAP * ~NOTFOUND",
            *how,
            page.as_uri(),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )


class Dom(HTMLParser):
    """The rendered DOM as chromium serialised it: elements with their attributes and text."""

    def __init__(self, text: str):
        super().__init__(convert_charrefs=True)
        self.elements: list[tuple[str, dict, list[str]]] = []
        self.open: list[tuple[str, dict, list[str]]] = []
        self.feed(text)

    def handle_starttag(self, tag, attrs):
        element = (tag, dict(attrs), [])
        self.elements.append(element)
        if tag not in ("meta", "br", "img", "input", "link"):
            self.open.append(element)

    def handle_endtag(self, tag):
        while self.open:
            if self.open.pop()[0] == tag:
                break

    def handle_data(self, data):
        for _, _, text in self.open:
            text.append(data)

    def all(self, tag: str | None = None, **attrs) -> list[tuple[dict, str]]:
        return [
            (a, "".join(t))
            for name, a, t in self.elements
            if (tag is None or name == tag) and all(a.get(k.replace("_", "-")) == v for k, v in attrs.items())
        ]


def with_attr(dom: Dom, tag: str, name: str) -> list[tuple[dict, str]]:
    return [(a, t) for a, t in dom.all(tag) if name in a]


@pytest.fixture(scope="module")
def fleet_run(tmp_path_factory):
    """One status run (--json and --html) over SSH robots, pull robots and a rollout's state."""
    base = tmp_path_factory.mktemp("status-page")
    key = paramiko.ECDSAKey.generate()
    key.write_private_key_file(str(base / "id_fleet"))
    hostile = report(health=HANDLER)
    hostile["current"]["rolled_back_from"] = {"id": "20261120T1Z-1", "reason": FORGED_ROW, "time": "2026-11-21T20:40Z"}
    servers = [
        sshserver.ssh_server(key, robot(report())),
        sshserver.ssh_server(key, robot(report(health="unhealthy"))),
        sshserver.ssh_server(key, robot(hostile)),
    ]
    hosts = {f"robot{n}": {"address": "127.0.0.1", "ssh_port": s.port} for n, s in enumerate(servers, 1)}
    hosts["robot4"] = {"address": "127.0.0.1", "ssh_port": sshserver.closed_port()}
    pull = {
        "pull_enabled": True,
        "pull_remote": "ssh://git@127.0.0.1:9/fleet",
        "pull_remote_host_keys": [KEY],
        "pull_interval": 600,
        "pull_jitter": 60,
    }
    hosts.update({name: {"address": "127.0.0.1", "ssh_port": 9, **pull} for name in ("robot5", "robot6", "robot7")})
    path = fleet(base, hosts, ssh_strict_host_key_checking="accept-new", ssh_connect_retries=0)

    bare = base / "fleet.git"
    subprocess.run(["git", "init", "-q", "--bare", str(bare)], check=True)
    when = datetime.datetime.now(UTC).replace(microsecond=0) - REPORT_AGE
    fresh = reports.build(
        "robot5",
        when,
        "applied",
        wave=0,
        seen={"version": 3, "release": "r3", "commit": "a" * 40},
        applied={"version": 3, "release": "r3", "commit": "a" * 40, "time": "2026-11-25T09:59:00Z"},
        host_keys=[KEY],
        key=KEY,
        status={
            "release": "20261125T0959Z-3",
            "release_state": "active",
            "image_refs": [IMAGE],
            "state": "running",
            "health": "healthy",
        },
    )
    failed = reports.build(
        "robot6",
        when,
        "failed",
        reason=f"release 3: {BOLD}",
        seen={"version": 3, "release": "r3", "commit": "a" * 40},
        applied={"version": 2, "release": "r2", "commit": "b" * 40, "time": "2026-11-24T09:59:00Z"},
        attempted={"version": 3, "result": "failed", "tries": 1},
        wave=1,
        host_keys=[KEY],
        key=KEY,
        status={"release": "20261124T0959Z-2", "health": "healthy"},
    )
    for body in (fresh, failed):
        transport.Remote(f"file://{bare}", base / body["robot"], str(base / "etc"), timeout=30).push_report(
            body["robot"], reports.to_bytes(body)
        )

    # the rollout's state as robotfleet rollout leaves it: wave 1 done, wave 2 stopped by a failure
    waves = [["robot1"], ["robot2", "robot3"], ["robot4"]]
    state = rollout_plan.new_state("0123456789abcdef", "inventories/robots.py", waves, {}, 0)
    state = rollout_plan.record_wave(state, 0, ["robot1"], {}, {})
    state = rollout_plan.record_wave(state, 1, ["robot2"], {"robot3": f"unhealthy: {BOLD}"}, {})
    rollout_plan.save_state(str(base / "rollouts" / "0123456789abcdef.json"), state)

    page = base / "fleet.html"
    started = time.time()
    argv = ["-m", "robotfleet", "status", "inventories/robots.py", "--json", "--html", str(page)]
    result = run(path, base, *argv, "--remote", f"file://{bare}")
    finished = time.time()
    yield result, page, state, (started, finished)
    for server in servers:
        server.close()


def test_the_page_a_browser_renders_says_what_status_json_says(fleet_run):
    result, page, state, (started, finished) = fleet_run
    assert result.returncode == 1, result.stderr  # robot6 failed its release
    rows = {r["host"]: r for r in json.loads(result.stdout)}
    rendered = browse(page, "--dump-dom")
    assert rendered.returncode == 0 and "<html" in rendered.stdout, rendered.stderr[-2000:]
    dom = Dom(rendered.stdout)

    # every host's row, its health and why, as --json has them
    shown = {a["data-host"]: a["data-health"] for a, _ in with_attr(dom, "tr", "data-health")}
    assert shown == EXPECTED
    assert set(shown) == set(rows)
    for name, row in rows.items():
        [(_, text)] = dom.all("tr", data_host=name, data_health=EXPECTED[name])
        why = row.get("error") or row.get("drift")
        assert why and why in text or EXPECTED[name] == "healthy", (name, why, text)
        assert (row.get("rollout") or "-") in text, (name, row.get("rollout"), text)
    # the counts, as the JSON's rows add up
    counts = {a["data-health"]: int(t.split()[0]) for a, t in dom.all("li") if "data-health" in a}
    assert counts == {health: list(EXPECTED.values()).count(health) for health in counts}
    assert sum(counts.values()) == len(rows)

    # the release history the payload reads: current, rolled back from, previous
    [(_, robot1)] = dom.all("tr", data_host="robot1")
    assert rows["robot1"]["release"] in robot1 and rows["robot1"]["previous"] in robot1
    [(_, robot3)] = dom.all("tr", data_host="robot3")
    assert f"rolled back from: 20261120T1Z-1 at 2026-11-21T20:40Z: {FORGED_ROW}" in robot3

    # the rollout's waves and their progress, as its state holds them
    def waves(kind):
        found = with_attr(dom, "li", "data-wave")
        return {
            a["data-wave"]: (int(a["data-done"]), int(a["data-total"])) for a, _ in found if a["data-rollout"] == kind
        }

    def outcomes(kind):
        found = with_attr(dom, "li", "data-outcome")
        return {a["data-host"]: a["data-outcome"] for a, _ in found if a["data-rollout"] == kind}

    assert waves("push") == {"1": (1, 1), "2": (1, 2), "3": (0, 1)}
    assert outcomes("push") == {h: rollout_plan.outcome(state, h) for wave in state["waves"] for h in wave}
    assert outcomes("push")["robot3"] == "failed" and dom.all(data_rollout_status="stopped")
    # a pull rollout's: release 3 as the robots placed themselves, the canary done, wave 1 failed, robot7 not there
    assert waves("pull") == {"0": (1, 1), "1": (0, 1), "none": (0, 1)}
    assert outcomes("pull") == {"robot5": "done", "robot6": "failed", "robot7": "pending"}

    # pull robots: the last report, its time as --json has it, its age as of the page's time
    [(_, taken)] = dom.all("time", id="taken")
    moment = datetime.datetime.fromisoformat(taken.replace("Z", "+00:00")).timestamp()
    assert int(started) <= moment <= finished
    pulled = {a["data-host"]: (a["data-report-age"], t) for a, t in with_attr(dom, "tr", "data-report-age")}
    assert set(pulled) == {"robot5", "robot6", "robot7"}
    assert rows["robot5"]["report"]["time"] in pulled["robot5"][1] and "applied 3" in pulled["robot5"][1]
    assert pulled["robot5"][0] in ("7 min", "8 min"), pulled["robot5"]
    assert pulled["robot7"][0] == "" and "never" in pulled["robot7"][1]

    # robots' markup is text: no forged row, no image, no bold, no script, nothing to fetch
    assert not dom.all(data_host="forged") and not dom.all("img") and not dom.all("b") and not dom.all("script")
    assert HANDLER in robot3 and BOLD in "".join(t for _, t in dom.all("tr", data_host="robot6"))
    assert not [a for _, a, _ in dom.elements if {"src", "href"} & set(a)]
    [(_, title)] = dom.all("title")
    assert title.startswith("Fleet status at ")


def png_size(path: Path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n", path
    return struct.unpack(">II", data[16:24])


def test_the_page_on_a_phone(fleet_run, tmp_path):
    """A phone's width: the page says it fits the device (viewport) and chromium draws it at that width."""
    _, page, _, _ = fleet_run
    text = page.read_text()
    assert '<meta name="viewport" content="width=device-width, initial-scale=1">' in text
    assert "@media (max-width: 720px)" in text
    shot = tmp_path / "phone.png"
    done = browse(page, f"--screenshot={shot}", "--window-size=390,844", "--hide-scrollbars")
    assert done.returncode == 0 and shot.is_file(), done.stderr[-2000:]
    assert png_size(shot) == (390, 844)
    assert shot.stat().st_size > 10_000  # drawn, not a blank page


def test_a_page_it_cannot_write_is_refused_before_any_host_is_contacted(tmp_path):
    server = sshserver.ssh_server()
    try:
        path = fleet(tmp_path, {"robot1": {"address": "127.0.0.1", "ssh_port": server.port}})
        page = tmp_path / "missing" / "fleet.html"
        result = run(path, tmp_path, "-m", "robotfleet", "status", "inventories/robots.py", "--html", str(page))
        assert result.returncode == 2, result.stderr
        assert result.stderr.strip() == (
            f"status: --html {page}: cannot write in {page.parent} (no such directory, or not writable); "
            "no host was contacted"
        )
        assert server.connections == 0
    finally:
        server.close()
