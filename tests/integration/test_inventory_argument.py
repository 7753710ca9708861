"""Every robotfleet command takes the fleet as it is kept (issue 39, item 1):
the fleet file, an Ansible INI or YAML inventory, or an inventory directory,
as INVENTORY or as Ansible's -i, as well as inventories/robots.py; and a
path of the wrong kind, given to pyinfra or to $ROBOT_FLEET, gets one line
naming the form that works (exit 2), never a traceback.  Real processes;
the robots are closed ports on 127.0.0.1: a command that read the fleet
dials them."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from tests.fixtures import PYINFRA, ROOT
from tests.integration import sshserver
from tests.integration.operator_side import fleet


@pytest.fixture(autouse=True)
def key(client_key):
    return client_key


def run(tmp_path: Path, *argv: str, env: dict | None = None) -> subprocess.CompletedProcess:
    """``argv`` in the checkout, with no $ROBOT_FLEET unless ``env`` has one."""
    (tmp_path / "known_hosts").touch()
    base = {
        "PATH": "/usr/bin:/bin",
        "PYINFRA_PROGRESS": "off",
        "HOME": str(tmp_path),
        "ROBOT_ROLLOUT_DIR": str(tmp_path / "rollouts"),
    }
    return subprocess.run(
        [sys.executable, *argv], cwd=ROOT, capture_output=True, text=True, timeout=120, env={**base, **(env or {})}
    )


def dialled(output: str) -> list[str]:
    """The robots a line says could not be reached at 127.0.0.1 (whatever its wording)."""
    return sorted(set(re.findall(r"^.*?\b(robot\d)\b.*127\.0\.0\.1:\d+", output, re.M)))


@pytest.fixture
def kinds(tmp_path) -> dict[str, Path]:
    """One fleet of two dead robots, kept three ways."""
    closed = sshserver.closed_port()
    yaml = fleet(
        tmp_path, {f"robot{i}": {"address": "127.0.0.1", "ssh_port": closed} for i in (1, 2)}, ssh_connect_retries=0
    )
    common = (
        f"payload_image=reg.example.com/p:1\nssh_user=ops\nssh_known_hosts_file={tmp_path}/known_hosts\n"
        f"ssh_connect_timeout=2\nssh_connect_retries=0\nssh_key={tmp_path}/id_fleet\n"
    )
    ini = tmp_path / "hosts.ini"
    ini.write_text(f"[robots]\nrobot[1:2] ansible_host=127.0.0.1 ansible_port={closed}\n\n[all:vars]\n{common}")
    directory = tmp_path / "ansible"
    (directory / "group_vars").mkdir(parents=True)
    (directory / "hosts").write_text(f"[robots]\nrobot[1:2] ansible_host=127.0.0.1 ansible_port={closed}\n")
    (directory / "group_vars" / "all.yml").write_text(common.replace("=", ": "))
    return {"yaml": yaml, "ini": ini, "directory": directory}


@pytest.mark.parametrize(
    "kind, form", [("yaml", "positional"), ("ini", "-i"), ("directory", "-i"), ("directory", "positional")]
)
def test_status_reads_the_fleet_however_it_is_kept(tmp_path, kinds, kind, form):
    path = str(kinds[kind])
    given = [path] if form == "positional" else ["-i", path]
    result = run(
        tmp_path,
        "-m",
        "robotfleet",
        "status",
        *given,
        "--json",
        env={"ROBOT_FLEET": str(tmp_path / "not-this-one.yaml")},
    )  # the argument is the fleet
    assert result.returncode == 3, result.stderr
    assert dialled(result.stderr) == ["robot1", "robot2"], result.stderr
    assert "Traceback" not in result.stderr


@pytest.mark.parametrize(
    "argv, code",
    [
        (["enroll", "-i", "{yaml}", "--yes"], 3),
        (["enroll", "{ini}", "--limit", "robot2", "--yes"], 3),
        (["rollout", "-i", "{directory}", "deploy.py", "--dry"], 3),
        (["rollout", "{yaml}", "--dry", "--limit", "robot1"], 3),
    ],
)
def test_every_command_that_contacts_robots_reads_it_too(tmp_path, kinds, argv, code):
    argv = [word.format(**kinds) for word in argv]
    result = run(tmp_path, "-m", "robotfleet", *argv)
    assert result.returncode == code, result.stderr[-3000:]
    assert dialled(result.stderr) == (
        ["robot2"] if "robot2" in argv else ["robot1"] if "robot1" in argv else ["robot1", "robot2"]
    ), result.stderr[-3000:]
    assert "Traceback" not in result.stderr


def test_pull_enroll_reads_it(tmp_path, kinds):
    result = run(tmp_path, "-m", "robotfleet", "pull-enroll", "-i", str(kinds["directory"]))
    line = f"{kinds['directory']}: no pull robot (pull_enabled: true) to enroll"
    assert (result.returncode, result.stderr.strip()) == (2, line), result.stderr


def test_bundle_reads_it(tmp_path, kinds):
    result = run(
        tmp_path, "-m", "robotfleet", "bundle", "robot1", "--out", str(tmp_path / "out"), "-i", str(kinds["directory"])
    )
    line = f"bundle: {kinds['directory']}: robot1 is not a pull robot (pull_enabled: true)"
    assert (result.returncode, result.stderr.strip()) == (2, line), result.stderr


def test_pyinfra_given_a_fleet_says_the_form_that_works(tmp_path, kinds):
    for path in (kinds["yaml"], kinds["directory"]):
        result = run(tmp_path, "-c", PYINFRA, "-y", str(path), "deploy.py", "--limit", "robot1")
        ours = [line for line in result.stderr.splitlines() if not line.startswith("--> ")]
        assert (result.returncode, ours) == (
            2,
            [
                f"{path}: pyinfra takes a Python inventory; it reads a fleet file or an Ansible inventory through "
                f"inventories/robots.py: ROBOT_FLEET={path} pyinfra inventories/robots.py -y deploy.py --limit robot1"
            ],
        ), result.stderr


def test_robot_fleet_naming_a_pyinfra_inventory_says_what_it_names(tmp_path):
    for argv in (
        ["-c", PYINFRA, "-y", "inventories/robots.py", "deploy.py"],
        ["-m", "robotfleet", "status", "inventories/robots.py"],
    ):
        result = run(tmp_path, *argv, env={"ROBOT_FLEET": "inventories/robots.py"})
        ours = [line for line in result.stderr.splitlines() if not line.startswith("--> ")]
        assert (result.returncode, ours) == (
            2,
            [
                "inventories/robots.py: a pyinfra inventory (Python), not a fleet file: $ROBOT_FLEET and --fleet name "
                "the fleet (inventories/robots.yaml, or an Ansible inventory file or directory)",
                "1 problem(s) in the fleet file; no host was contacted.",
            ],
        ), (argv, result.stderr)


@pytest.mark.parametrize(
    "argv, line",
    [
        (
            ["status", "{tmp}/missing.yaml"],
            "{tmp}/missing.yaml: no such inventory: give the fleet file "
            "(inventories/robots.yaml), an Ansible inventory file or directory, or a pyinfra inventory "
            "(inventories/robots.py)",
        ),
        (
            ["enroll"],
            "robotfleet enroll: error: no inventory: give the fleet (inventories/robots.yaml, an Ansible "
            "inventory file or directory) or inventories/robots.py, as INVENTORY or -i INVENTORY",
        ),
        (
            ["status", "inventories/robots.py", "-i", "{tmp}/hosts"],
            "robotfleet status: error: the inventory given twice (inventories/robots.py and -i {tmp}/hosts); give one",
        ),
    ],
)
def test_no_inventory_or_two_is_refused_in_one_line(tmp_path, argv, line):
    result = run(tmp_path, "-m", "robotfleet", *[word.format(tmp=tmp_path) for word in argv])
    assert result.returncode == 2, result.stderr
    assert result.stderr.splitlines()[-1] == line.format(tmp=tmp_path), result.stderr


def test_a_python_file_that_is_no_inventory_is_one_line(tmp_path):
    result = run(tmp_path, "-m", "robotfleet", "status", "deploy.py")
    assert result.returncode == 2, result.stderr
    assert len(result.stderr.splitlines()) == 1 and "Traceback" not in result.stderr, result.stderr
    assert result.stderr.startswith("deploy.py: not an inventory pyinfra can load (")
    assert result.stderr.rstrip().endswith(
        "give the fleet file (inventories/robots.yaml), an Ansible inventory file "
        "or directory, or inventories/robots.py"
    )
