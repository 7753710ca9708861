"""Bad fleet data through pyinfra's real CLI (tests/unit/test_validation.py
checks the lines themselves): refused before any connection, one line, no
traceback; the local inventory reads the fleet file."""

from tests.fixtures import ROOT, pyinfra


def test_cli_refuses_bad_fleet_before_connecting(tmp_path):
    """The real pyinfra CLI: non-zero exit, our lines, no traceback, no connection."""
    (tmp_path / "inventories").mkdir()
    (tmp_path / "inventories" / "robots.py").write_text((ROOT / "inventories" / "robots.py").read_text())
    (tmp_path / "inventories" / "robots.yaml").write_text(
        "robots:\n  hosts:\n    robot3:\n      address: 192.0.2.1\n"
        "      payload_image: reg.example.com/p:1\n      udev_sensors:\n"
        "        - {name: cam, subsystem: tty, serial: 42}\n"
    )
    (tmp_path / "deploy.py").write_text("raise SystemExit('deploy must not run')\n")
    proc = pyinfra(
        "-y",
        "inventories/robots.py",
        "deploy.py",
        cwd=tmp_path,
        timeout=60,
        env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"},
    )
    assert proc.returncode == 2
    assert "inventories/robots.yaml: robot3.udev_sensors[0].serial: expected a string, got 42; quote it" in proc.stderr
    assert "Traceback" not in proc.stderr + proc.stdout
    assert "Connecting" not in proc.stderr + proc.stdout


def _pyinfra(*args, env=None):
    return pyinfra(*args, timeout=60, env={"PATH": "/usr/bin:/bin", **(env or {})})


def test_mistyped_inventory_path_is_refused():
    proc = _pyinfra("-y", "inventories/robot.py", "deploy.py")
    assert proc.returncode == 2 and "inventories/robot.py: no such file" in proc.stderr


def test_local_inventory_is_this_laptop_from_the_fleet_file():
    proc = _pyinfra("inventories/local.py", "debug-inventory", env={"ROBOT_FLEET_HOST": "alice-laptop"})
    assert proc.returncode == 0, proc.stderr
    assert "[@local]" in proc.stderr + proc.stdout and '"x11_user": "alice"' in proc.stderr + proc.stdout
    proc = _pyinfra("inventories/local.py", "debug-inventory", env={"ROBOT_FLEET_HOST": "nobody"})
    assert proc.returncode == 2 and "no laptop named 'nobody' (laptops: alice-laptop)" in proc.stderr
