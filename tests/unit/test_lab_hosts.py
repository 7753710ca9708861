"""Pure parts of the lab's host handling."""

import pytest


def test_known_hosts_line_uses_bracketed_host_and_port(hosts):
    key = "ssh-ed25519 AAAAC3NzaC1lZDI1NTE5AAAAIOo root@robot1"
    assert hosts.known_hosts_line(22001, key) == "[127.0.0.1]:22001 ssh-ed25519 AAAAC3NzaC1lZDI1NTE5AAAAIOo"
    assert hosts.known_hosts_line(22, key) == "127.0.0.1 ssh-ed25519 AAAAC3NzaC1lZDI1NTE5AAAAIOo"


def test_known_hosts_line_is_what_paramiko_looks_up(hosts, tmp_path):
    paramiko = pytest.importorskip("paramiko")
    line = hosts.known_hosts_line(
        22001, "ssh-ed25519 AAAAC3NzaC1lZDI1NTE5AAAAIEv7c1MIxS1aDiHnkvLJpm9leEXrCUGb/lZ0/a7wfecX x"
    )
    path = tmp_path / "known_hosts"
    path.write_text(line + "\n")
    keys = paramiko.HostKeys(str(path))
    assert "ssh-ed25519" in keys.lookup("[127.0.0.1]:22001")


def test_plan_hosts_names_groups_and_architectures(hosts):
    assert hosts.plan_hosts(2, 1) == [
        ("robot1", "robots", "amd64"),
        ("robot2", "robots", "amd64"),
        ("laptop1", "laptops", "amd64"),
    ]
    assert hosts.plan_hosts(1, 0, arm64_robots=2) == [
        ("robot1", "robots", "amd64"),
        ("pi1", "robots", "arm64"),
        ("pi2", "robots", "arm64"),
    ]
    assert hosts.plan_hosts(0, 0) == []


def test_emulated_hosts_get_longer_to_boot(hosts):
    assert hosts.ready_timeout("arm64") == hosts.ready_timeout("amd64") * hosts.EMULATED_SLOWDOWN


def test_sensors_from_inventory(hosts, tmp_path):
    path = tmp_path / "lab.yaml"
    path.write_text(
        "robots:\n  hosts:\n    robot1:\n      udev_sensors:\n        - {name: lidar, serial: x}\n"
        "        - {name: imu}\n    robot2: {}\nlaptops:\n  hosts:\n    laptop1: {}\n"
    )
    assert hosts.sensors_from_inventory(path) == {"robot1": ["lidar", "imu"], "robot2": []}
    assert hosts.sensors_from_inventory(tmp_path / "missing.yaml") == {}


def test_one_sensor_list_applies_to_every_robot_and_names_are_checked(hosts, engine):
    assert hosts._sensors_by_host(["lidar"], ["robot1", "pi1"]) == {"robot1": ["lidar"], "pi1": ["lidar"]}
    with pytest.raises(engine.LabError):
        hosts._sensors_by_host(["../etc/passwd"], ["robot1"])


def test_apt_proxy_goes_direct_to_the_services_host(hosts):
    conf = hosts.apt_proxy_conf("lab-services")
    assert 'Acquire::http::Proxy "http://lab-services:3142";' in conf
    assert 'Acquire::http::Proxy::lab-services "DIRECT";' in conf


def test_prefix_must_be_a_hostname_part(hosts, engine):
    assert hosts.check_prefix("e2e") == "e2e"
    for bad in ("", "Lab", "a_b", "-x", "a" * 40):
        with pytest.raises(engine.LabError):
            hosts.check_prefix(bad)


def test_engine_is_not_started_when_we_may_not(engine, monkeypatch):
    monkeypatch.delenv("DOCKER_HOST", raising=False)
    monkeypatch.setattr(engine.os, "geteuid", lambda: 1000)
    assert engine._why_we_cannot_start_dockerd() == "not root"
    monkeypatch.setenv("DOCKER_HOST", "tcp://127.0.0.1:1")
    assert "does not answer" in engine._why_we_cannot_start_dockerd()


def test_no_e2e_module_but_the_session_fixture_takes_the_session_lab_up_or_down():
    """A module that took the session's lab (prefix PREFIX) down for a lab of
    its own left every module after it without hosts (the CI run of stop 31):
    such a module uses one_robot_lab, a prefix of its own."""
    import re
    from pathlib import Path

    e2e = Path(__file__).resolve().parents[1] / "e2e"
    offenders = [
        path.name
        for path in sorted(e2e.glob("test_*.py"))
        if re.search(r"hosts\.(up|down|reset)\(\s*PREFIX\b", path.read_text())
    ]
    assert offenders == []
    assert re.search(r"hosts\.down\(PREFIX\)", (e2e / "conftest.py").read_text())


def test_the_demo_s_hints_name_modules_that_exist():
    """The demo printed `python -m engine status` long after engine/ became robotfleet/."""
    import importlib.util
    import re
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "lab" / "demo.py").read_text()
    modules = re.findall(r"\{python\} -m ([\w.]+)", text)
    assert modules and [m for m in modules if importlib.util.find_spec(m) is None] == []
