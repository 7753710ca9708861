"""What the unit layer can see: the snapshot answers only declared reads and
the harness records stdin (what importing patches is checked in a fresh
interpreter by tests/integration/test_harness.py)."""

import dataclasses

import pytest

from robotfleet.host import snapshot as hoststate
from robotfleet.host.snapshot import FileState, Readings, UndeclaredRead
from tests.unit.harness import LAPTOP, ROBOT, converged, everything_sent, find, fresh_host, plan, written_files


def test_snapshot_refuses_a_read_nobody_declared():
    query = {"files": ["/etc/docker/daemon.json"], "packages": ["docker-ce"], "probes": {"p": "true"}}
    snap = hoststate.parse(["file\t/etc/docker/daemon.json\tnone", "probe\tp\t"], query)
    assert snap.files.get("/etc/docker/daemon.json") is None  # declared, absent on the host
    assert "docker-ce" not in snap.packages and snap.probes.get("p") == ""
    with pytest.raises(UndeclaredRead) as error:
        snap.files.get("/etc/apt/keyrings/docker.asc")
    assert str(error.value) == (
        "snapshot: files '/etc/apt/keyrings/docker.asc' was not read from the host; "
        "add it to the role's declare_reads (query.files)"
    )
    for read in (
        lambda: "gpg" in snap.packages,
        lambda: snap.units.get("docker.service"),
        lambda: snap.unit_active("docker.service"),
        lambda: snap.installed("gpg"),
        lambda: snap.users["ops"],
        lambda: snap.commands.get("gpg"),
    ):
        with pytest.raises(UndeclaredRead):
            read()


def test_readings_behave_like_a_dict_for_declared_keys():
    readings = Readings("files", ["/a", "/b"], {"/a": FileState("dir", None, "755", "root", "root")})
    assert readings["/a"].kind == "dir" and readings.get("/b", "x") == "x" and "/b" not in readings
    with pytest.raises(KeyError):
        readings["/b"]


def test_harness_answers_only_declared_reads(monkeypatch):
    """A role that stops declaring daemon.json (so a real host would look as
    if it had none and Docker would restart every run) fails the plan."""
    from roles import docker

    declare = docker.ROLE.reads

    def forgetful(data, query):
        declare(data, query)
        query.files.discard(docker.DAEMON_JSON)

    monkeypatch.setattr(docker, "ROLE", dataclasses.replace(docker.ROLE, reads=forgetful))
    with pytest.raises(UndeclaredRead, match="daemon.json' was not read from the host"):
        plan({"r1": ("robots", ROBOT, converged("robots", ROBOT, "debian-13"))})


def test_harness_records_the_query_per_host():
    result = plan(
        {
            "r1": ("robots", ROBOT, fresh_host("debian-13")),
            "l1": ("laptops", LAPTOP, fresh_host("ubuntu-24.04", users=("alice",))),
        }
    )
    assert "/etc/docker/daemon.json" in result.queries["r1"]["files"]
    assert "xauth" in result.queries["l1"]["packages"] and "xauth" not in result.queries["r1"]["packages"]


def test_file_contents_are_recorded_from_stdin():
    commands = plan({"r1": ("robots", ROBOT, fresh_host("debian-13"))})["r1"]
    daemon = written_files(commands)["/etc/docker/daemon.json"]
    assert '"live-restore": true' in daemon
    # The content is not on the command line: only stdin carries it.
    assert not find(commands, "live-restore")
    assert "live-restore" in everything_sent(commands)


def test_nothing_sent_to_a_laptop_mentions_xhost():
    commands = plan({"l1": ("laptops", LAPTOP, fresh_host("ubuntu-24.04", users=("alice",)))})["l1"]
    sent = everything_sent(commands)
    assert "xauth" in sent and "nmerge" in sent  # the cookie script did go over stdin
    assert "xhost" not in sent.replace("`xhost +`", "")


def test_registry_token_travels_only_as_stdin_of_the_login(monkeypatch):
    monkeypatch.setenv("PAYLOAD_REGISTRY_USERNAME", "robot")
    monkeypatch.setenv("PAYLOAD_REGISTRY_PASSWORD", "s3cret-token")
    commands = plan({"r1": ("robots", ROBOT, converged("robots", ROBOT, "debian-13"))})["r1"]
    carrying = [c for c in commands if "s3cret-token" in c or "s3cret-token" in c.stdin]
    assert len(carrying) == 1
    assert "docker login reg.example.com --username robot --password-stdin >/dev/null" in carrying[0]
    assert "s3cret-token" not in carrying[0]
    assert carrying[0].stdin.rstrip("\n").endswith("s3cret-token")


# --- decisions a reviewer broke without any unit test noticing (issue 10) ----


@pytest.mark.parametrize(
    "role, kind, key",
    [
        ("docker", "files", "/etc/docker/daemon.json"),
        ("docker", "files", "/etc/apt/keyrings/docker.asc"),
        ("docker", "files", "/etc/apt/sources.list.d/docker.sources"),
        ("docker", "probes", "docker_key_fingerprints"),
        ("docker", "units", "docker.service"),
        ("payload", "files", "/etc/systemd/system/robot-payload.service"),
        ("payload", "units", "robot-payload.service"),
    ],
)
def test_a_role_that_stops_declaring_a_read_fails_the_plan(monkeypatch, role, kind, key):
    import importlib

    module = importlib.import_module(f"roles.{role}")
    declare = module.ROLE.reads

    def forgetful(data, query):
        declare(data, query)
        readings = getattr(query, kind)
        readings.pop(key) if isinstance(readings, dict) else readings.discard(key)

    monkeypatch.setattr(module, "ROLE", dataclasses.replace(module.ROLE, reads=forgetful))
    with pytest.raises(UndeclaredRead, match=f"{kind} '{key}' was not read"):
        plan({"r1": ("robots", ROBOT, converged("robots", ROBOT, "debian-13"))})


@pytest.mark.parametrize("active", ["inactive", "failed"])
def test_payload_down_on_a_converged_robot_is_released_again(active):
    snap = converged("robots", ROBOT, "debian-13")
    snap.units["robot-payload.service"] = ("enabled", active)
    commands = plan({"r1": ("robots", ROBOT, snap)})["r1"]
    assert len(commands) == 1 and "payloadctl apply" in commands[0] and "--restart" not in commands[0]


def test_docker_service_enabled_false_disables_docker_at_boot():
    data = {**ROBOT, "docker_service_enabled": False}
    assert plan({"r1": ("robots", data, converged("robots", ROBOT, "debian-13"))})["r1"] == [
        "sh -c 'systemctl disable docker.service'"
    ]
    fresh = plan({"r1": ("robots", data, fresh_host("debian-13"))})["r1"]
    assert find(fresh, "systemctl start docker.service") and not find(fresh, "systemctl enable docker.service")


def test_rollback_respects_the_update_lock_unless_forced():
    snap = converged("robots", ROBOT, "debian-13")
    commands = plan({"r1": ("robots", ROBOT, snap)}, deploy_file="rollback.py")["r1"]
    assert len(commands) == 1
    # The lock file and the timeouts come from the release's own spec on the robot.
    assert "payloadctl rollback --dir /var/lib/robot-payload --by " in commands[0]
    assert "--force" not in commands[0]
    forced = plan({"r1": ("robots", {**ROBOT, "payload_force": True}, snap)}, deploy_file="rollback.py")["r1"]
    assert "--force" in forced[0]


def test_robots_and_laptops_in_one_run_order_their_operations_without_a_cycle():
    """pyinfra's CLI tells operations apart by their call lines: roles called
    from one loop line must still get a place of their own, or a robot (udev)
    and a laptop (x11, distro engine) in one run make a cycle in pyinfra's
    operation order and nothing runs (seen on the simulated fleet)."""
    laptop = {**LAPTOP, "docker_source": "distro"}
    result = plan(
        {
            "r1": ("robots", ROBOT, fresh_host("debian-13")),
            "r2": ("robots", ROBOT, fresh_host("debian-13")),
            "l1": ("laptops", laptop, fresh_host("debian-13", users=("alice",))),
        }
    )
    assert result.failed == set()
    assert find(result["r1"], "udevadm") and find(result["l1"], "xauth") and find(result["l1"], "payloadctl apply")


def test_deploy_py_names_its_roles_and_a_misspelt_name_is_one_line(tmp_path):
    from robotfleet import deploy_roles

    deploy = tmp_path / "deploy.py"
    deploy.write_text(
        "from robotfleet.provision import provision\nfrom roles import named\n"
        'ROLES = named("time", "docker")\nprovision(ROLES)\n'
    )
    assert [role.name for role in deploy_roles.roles(deploy)] == ["time", "docker"]
    deploy = tmp_path / "misspelt.py"
    deploy.write_text(
        "from robotfleet.provision import provision\nfrom roles import named\n"
        'ROLES = named("docker", "usres")\nprovision(ROLES)\n'
    )
    with pytest.raises(LookupError) as error:
        deploy_roles.roles(deploy)
    assert str(error.value) == "deploy.py: ROLES names 'usres', but there is no roles/usres/"
