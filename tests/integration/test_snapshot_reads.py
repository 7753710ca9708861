"""The snapshot's cheaper reads give the answers of the commands they
replace, checked against those commands on this machine: dpkg --audit on
dpkg databases in every state it reports, the packages from dpkg's status
file, the units from one systemctl show, and the payload's containers from
the engine's API against what the docker CLI printed."""

from __future__ import annotations

import os
import shlex
import shutil
import subprocess
from pathlib import Path

import pytest

from robotfleet.host import snapshot as hoststate
from robotfleet.host import snapshot_sh
from tests.integration.dpkg_databases import CASES, admindir, audit_before, audit_now, both_files, stanza


@pytest.mark.parametrize("case", sorted(CASES))
def test_dpkg_audit_probe_says_what_dpkg_audit_says(tmp_path, case):
    stanzas, info = CASES[case]
    d = admindir(tmp_path, stanzas, info)
    before = audit_before(d)
    assert (before == "") == (case == "healthy")  # the case is what it says
    assert audit_now(d) == before


def test_dpkg_audit_probe_with_a_journal_or_an_old_database(tmp_path):
    stanzas, info = CASES["healthy"]
    d = admindir(tmp_path, stanzas, info, journal=True)
    assert audit_now(d) == audit_before(d) != ""
    old = admindir(tmp_path / "old", [stanza("lib", multiarch="same")], both_files("lib"), multiarch_db=False)
    assert audit_now(old) == audit_before(old) == ""


def test_dpkg_audit_probe_on_this_machine():
    assert audit_now(Path("/var/lib/dpkg")) == audit_before(Path("/var/lib/dpkg"))


def test_packages_are_read_as_dpkg_query_reads_them(tmp_path):
    """The status file read with awk gives dpkg-query's lines; with a journal
    dpkg-query answers (it reads the journal too)."""
    names = ["dpkg", "coreutils", "surely-not-a-package", "libc6"]
    script = hoststate.snapshot_script(packages=names)
    awk = subprocess.run(["sh", "-c", script], capture_output=True, text=True, check=True).stdout
    query = subprocess.run(
        ["dpkg-query", "-W", "-f=pkg\\t${Package}\\t${Status}\\t${Version}\\n", *names], capture_output=True, text=True
    ).stdout
    assert sorted(line for line in awk.splitlines() if line.startswith("pkg\t")) == sorted(query.splitlines())


def test_packages_are_asked_of_dpkg_query_while_dpkg_s_journal_holds_a_run(tmp_path, monkeypatch):
    d = admindir(tmp_path, [stanza("a"), stanza("b")])
    monkeypatch.setattr(snapshot_sh, "DPKG_DIR", str(d))
    log = tmp_path / "started"
    real = f"{shutil.which('dpkg-query')} --admindir={shlex.quote(str(d))}"
    (tmp_path / "dpkg-query").write_text(f'#!/bin/sh\necho dpkg-query >> {shlex.quote(str(log))}\nexec {real} "$@"\n')
    (tmp_path / "dpkg-query").chmod(0o755)
    env = dict(os.environ, PATH=f"{tmp_path}:{os.environ['PATH']}")

    def packages():
        query = {"packages": ["a", "b"]}
        script = hoststate.snapshot_script(**query)
        out = subprocess.run(["sh", "-c", script], capture_output=True, text=True, check=True, env=env).stdout
        return dict(hoststate.parse(out.splitlines(), query).packages), log.exists()

    assert packages() == ({"a": "1.0", "b": "1.0"}, False)  # the status file, with awk
    (d / "status").write_text((d / "status").read_text().replace("Version: 1.0", "Version: 2.0", 1))  # an upgrade
    assert packages() == ({"a": "2.0", "b": "1.0"}, False)
    (d / "updates" / "0000").write_text(stanza("a").replace("Version: 1.0", "Version: 3.0"))  # an unfinished run
    assert packages() == ({"a": "3.0", "b": "1.0"}, True)  # dpkg-query reads the journal too


def test_users_groups_are_read_as_id_reads_them():
    """One groups for every user: id -nG's answer for each, "no such user"
    for a name that is not one (nor a prefix of one that is)."""
    users = ["root", "daemon", "nobody", "roo", "surely-not-a-user"]
    snap = hoststate.parse(
        subprocess.run(
            ["sh", "-c", hoststate.snapshot_script(users=users)], capture_output=True, text=True
        ).stdout.splitlines(),
        {"users": users},
    )
    for user in users:
        ids = subprocess.run(["id", "-nG", user], capture_output=True, text=True)
        assert snap.users[user] == (ids.stdout.split() if ids.returncode == 0 else None), user


FAKE_SYSTEMCTL = """#!/bin/sh
# show -p UnitFileState,ActiveState -- UNIT...: a block a unit, blank lines
# between, as systemd does; with NOBUS set, nothing (no systemd to ask), and
# is-enabled / is-active UNIT say what they can, as systemd 257 does.
verb=$1; shift
echo "$verb $*" >> "$LOG"
if [ "$verb" = show ]; then
  [ -n "$NOBUS" ] && exit 1
  shift 3; first=1
  for u; do
    [ -n "$first" ] || echo; first=
    case $u in
      docker.service|alias.service) printf 'ActiveState=active\\nUnitFileState=enabled\\n' ;;
      masked.service) printf 'UnitFileState=masked\\nActiveState=inactive\\n' ;;
      *) printf 'ActiveState=inactive\\nUnitFileState=\\n' ;;
    esac
  done
  exit 0
fi
for u; do
  case $verb:$u in
    is-enabled:docker.service) echo enabled ;;
    is-enabled:alias.service) echo alias ;;
    is-enabled:*) echo not-found ;;
    is-active:docker.service|is-active:alias.service) echo active ;;
    is-active:*) echo inactive ;;
  esac
done
"""


@pytest.mark.parametrize("bus", [True, False])
def test_units_are_asked_at_once_and_one_by_one_where_systemd_cannot_say(tmp_path, bus):
    (tmp_path / "systemctl").write_text(FAKE_SYSTEMCTL)
    (tmp_path / "systemctl").chmod(0o755)
    log = tmp_path / "log"
    env = dict(os.environ, PATH=f"{tmp_path}:{os.environ['PATH']}", LOG=str(log), NOBUS="" if bus else "1")
    units = ["alias.service", "docker.service", "gone.service", "masked.service"]
    out = subprocess.run(
        ["sh", "-c", hoststate.snapshot_script(units=units)], capture_output=True, text=True, check=True, env=env
    )
    snap = hoststate.parse(out.stdout.splitlines(), {"units": units})
    assert dict(snap.units) == {
        "alias.service": ("enabled" if bus else "alias", "active"),
        "docker.service": ("enabled", "active"),
        "gone.service": ("" if bus else "not-found", "inactive"),
        "masked.service": ("masked" if bus else "not-found", "inactive"),
    }
    assert snap.unit_enabled("alias.service") and not snap.unit_enabled("masked.service")
    calls = log.read_text().splitlines()
    assert calls[0] == "show -p UnitFileState,ActiveState -- " + " ".join(units)
    assert len(calls) == (1 if bus else 1 + 2 * len(units))


@pytest.mark.parametrize("answer", ["", "ActiveState=active\n", "A=1\n\nB=2\n\nC=3\n\nD=4\n\nE=5\n", "garbled\n"])
def test_a_systemctl_show_answer_that_does_not_add_up_is_not_read(tmp_path, answer):
    """Fewer blocks than units, more, or lines that are not properties: each
    unit asked alone, nothing read from the answer."""
    fake = f'#!/bin/sh\n[ "$1" = show ] && printf %s {shlex.quote(answer)} && exit 0\necho alone\n'
    (tmp_path / "systemctl").write_text(fake)
    (tmp_path / "systemctl").chmod(0o755)
    env = dict(os.environ, PATH=f"{tmp_path}:{os.environ['PATH']}")
    units = ["a.service", "b.service"]
    out = subprocess.run(
        ["sh", "-c", hoststate.snapshot_script(units=units)], capture_output=True, text=True, check=True, env=env
    )
    assert dict(hoststate.parse(out.stdout.splitlines(), {"units": units}).units) == {
        u: ("alone", "alone") for u in units
    }


ENGINE = """
import http.server, json, socketserver, sys

routes = json.load(open(sys.argv[1]))

class Handler(http.server.BaseHTTPRequestHandler):
    def do_GET(self):
        status, body = routes.get(self.path, (404, '{"message":"No such container"}'))
        data = body.encode()
        self.send_response(status)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(data)))
        self.end_headers()
        self.wfile.write(data)

    def log_message(self, *args):
        pass

class Server(socketserver.UnixStreamServer):
    def get_request(self):
        request, _ = super().get_request()
        return request, ("local", 0)

Server(sys.argv[2], Handler).serve_forever()
"""


def engine(tmp_path, routes: dict[str, tuple[int, str]]):
    """An HTTP server on a unix socket answering GETs from ``routes`` (path ->
    status, body), as dockerd does; in its own process (the test process may
    have gevent's sockets)."""
    import json
    import sys
    import time

    (tmp_path / "routes.json").write_text(json.dumps(routes))
    path = tmp_path / "docker.sock"
    server = subprocess.Popen([sys.executable, "-c", ENGINE, str(tmp_path / "routes.json"), str(path)])
    deadline = time.monotonic() + 10
    while not path.exists() and time.monotonic() < deadline:
        time.sleep(0.02)
    return server, str(path)


def inspect(cid, name, image, labels, running, policy):
    import json

    return json.dumps(
        {
            "Id": cid,
            "Name": name,
            "Config": {"Image": image, "Labels": labels},
            "State": {"Running": running},
            "HostConfig": {"RestartPolicy": {"Name": policy}},
        }
    )


def test_the_containers_are_read_from_the_engines_api_as_the_cli_printed_them(tmp_path, monkeypatch, capsys):
    import json

    from roles.payload import containers, docker_read

    listing = [
        {
            "Id": "a" * 64,
            "State": "running",
            "Status": "Up 3 hours (healthy)",
            "Labels": {containers.LABEL: "robot-payload"},
        },
        {"Id": "b" * 64, "State": "exited", "Status": "Exited (0) 2 days ago", "Labels": {}},
        {"Id": "c" * 64, "State": "running", "Status": "Up 1 second", "Labels": None},
        {"Id": "d" * 64, "State": "created", "Status": "Created", "Labels": {"other": "x"}},  # gone before inspect
    ]
    routes = {
        "/containers/json?all=1": (200, json.dumps(listing)),
        f"/containers/{'a' * 64}/json": (
            200,
            inspect(
                "a" * 64,
                "/robot-payload-payload-1",
                "reg/ros/payload:1",
                {containers.LABEL: "robot-payload"},
                True,
                "unless-stopped",
            ),
        ),
        f"/containers/{'b' * 64}/json": (
            200,
            inspect("b" * 64, "/old<&>é", "reg/ros/payload:0.9", {}, False, "always"),
        ),
        f"/containers/{'c' * 64}/json": (200, inspect("c" * 64, "/plain", "debian", None, True, "")),
    }
    server, path = engine(tmp_path, routes)
    monkeypatch.setattr(docker_read, "SOCKET", path)
    for name in ("DOCKER_HOST", "DOCKER_CONTEXT", "DOCKER_CONFIG"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("HOME", str(tmp_path))
    try:
        assert docker_read.main(["-c", "robot-payload", "foreign"]) == 0
    finally:
        server.kill()
        server.wait()
    out = capsys.readouterr().out
    # What `docker ps --format` and `docker inspect -f '{{json (printf ...)}}'` print (Go's JSON escapes
    # <, > and &; a missing label is "" in the CLI's typed map, docker 26 and 28).
    assert out == (
        "c\trunning\tUp 3 hours (healthy)\n"
        f'f\t"{"a" * 64}\\t/robot-payload-payload-1\\treg/ros/payload:1\\trobot-payload\\ttrue\\tunless-stopped"\n'
        f'f\t"{"b" * 64}\\t/old\\u003c\\u0026\\u003eé\\treg/ros/payload:0.9\\t\\tfalse\\talways"\n'
        f'f\t"{"c" * 64}\\t/plain\\tdebian\\t\\ttrue\\t"\n'
    )
    assert containers.part(out, "c") == "running\tUp 3 hours (healthy)\n"
    assert [json.loads(line).split("\t")[1] for line in containers.part(out, "f").splitlines()] == [
        "/robot-payload-payload-1",
        "/old<&>é",
        "/plain",
    ]


def test_the_containers_probe_leaves_another_engine_to_the_docker_cli(tmp_path):
    """DOCKER_HOST (or a context) names an engine the CLI would ask: the
    probe asks the CLI (here a stand-in that says who it is)."""
    from roles.payload import containers

    (tmp_path / "docker").write_text('#!/bin/sh\necho "cli $*" | head -c 60; echo\n')
    (tmp_path / "docker").chmod(0o755)
    env = dict(os.environ, PATH=f"{tmp_path}:{os.environ['PATH']}", DOCKER_HOST="tcp://elsewhere:2375")
    out = subprocess.run(
        ["sh", "-c", containers.probe("robot-payload", foreign=False)], capture_output=True, text=True, env=env
    ).stdout
    assert out.startswith("cli ps -a --filter label=com.docker.compose")
    env.pop("DOCKER_HOST")
    (tmp_path / ".docker").mkdir()
    (tmp_path / ".docker" / "config.json").write_text('{"currentContext": "remote"}')
    env["HOME"] = str(tmp_path)
    out = subprocess.run(
        ["sh", "-c", containers.probe("robot-payload", foreign=False)], capture_output=True, text=True, env=env
    ).stdout
    assert out.startswith("cli ps -a")
