"""The operator's install and commands on the Pythons Ubuntu ships (issue 51
item 1): 22.04's 3.10 and 24.04's 3.12 (tests/pythons.py), beside the main
interpreter.  Before, `pip install -e .` ended on 3.10 with "No matching
distribution found for check-jsonschema>=0.39".

Each Python gets a fresh venv with the README's install (`pip install -e .`
of this checkout), offline: its wheels are the ones `robotfleet publish`
fetches for a robot of that Python (robotfleet/pull/operator/wheels.py),
kept in .lab/cache/python-wheels, so only a first run asks the index; the
venvs are built at once.  Then the operator's commands run in each, and
each says what it says under the main interpreter: the fleet check's lines
for a bad fleet (a setting's typo, a compose key the Compose schema
refuses), `robotfleet inventory`, pyinfra's `--dry` planning (the unit
harness's @fake hosts, as tests/integration/test_dry_and_diff.py) and
`robotfleet status` against robots that cannot be reached."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from functools import lru_cache
from pathlib import Path

import pytest

from robotfleet.pull.operator import wheels
from robotfleet.pull.protocol import platforms
from tests import pythons
from tests.fixtures import ROOT
from tests.integration import sshserver
from tests.integration.operator_side import dry_run, fleet

CACHE = ROOT / ".lab" / "cache" / "python-wheels"
BAD_COMPOSE = {
    "payload_image": None,
    "payload_services": {"payload": {"image": "reg.example.com/ros/payload:1.0", "restatr": "always"}},
}


def _venv(version: str, base: Path) -> Path:
    """A fresh venv of Python ``version`` with this checkout installed as the README says, offline."""
    python = pythons.find(version)
    key = platforms.platform_key(tuple(int(part) for part in version.split(".")))
    requirements = wheels.requirements_of((ROOT / "pyproject.toml").read_bytes())
    found = wheels.build_wheelhouse(requirements, key, CACHE)
    build = wheels.build_wheelhouse(["setuptools>=64"], key, CACHE / "build")  # pip's build of the checkout
    env = base / f"venv-{version}"
    # without ensurepip's copy of pip (seconds of CPU): this interpreter's pip installs for it (--python)
    subprocess.run([str(python), "-m", "venv", "--without-pip", str(env)], check=True, capture_output=True)
    installed = subprocess.run(
        [sys.executable, "-m", "pip", "--python", str(env / "bin" / "python"), "install", "-q"]
        + ["--disable-pip-version-check", "--no-index"]
        + ["--find-links", str(found[0].parent), "--find-links", str(build[0].parent), "-e", str(ROOT)],
        capture_output=True,
        text=True,
        timeout=600,
        env={**os.environ, "PIP_CONFIG_FILE": os.devnull},
    )
    assert installed.returncode == 0, f"pip install -e . on Python {version}:\n{installed.stderr[-3000:]}"
    return env / "bin" / "python"


@pytest.fixture(scope="module")
def venvs(tmp_path_factory) -> dict[str, Path]:
    """Python version -> its venv's python (the versions this machine has)."""
    base = tmp_path_factory.mktemp("pythons")
    here = [version for version in pythons.OPERATOR_PYTHONS if pythons.find(version)]
    with ThreadPoolExecutor(max_workers=2) as pool:
        built = dict(zip(here, pool.map(lambda version: _venv(version, base), here)))
    return built


@pytest.fixture(params=pythons.OPERATOR_PYTHONS)
def python(request, venvs) -> Path:
    pythons.require(request.param)
    return venvs[request.param]


@pytest.fixture(autouse=True)
def key(client_key):
    return client_key


def run(python, tmp_path, fleet_path, *argv) -> subprocess.CompletedProcess:
    """A command as the operator runs it in the checkout (the fleet in $ROBOT_FLEET), its output's lines."""
    (tmp_path / "known_hosts").touch()
    env = {"PATH": "/usr/bin:/bin", "ROBOT_FLEET": str(fleet_path), "PYINFRA_PROGRESS": "off", "HOME": str(tmp_path)}
    return subprocess.run(
        [str(python), *argv], cwd=ROOT, capture_output=True, text=True, timeout=300, env={**env, "PYTHONPATH": ""}
    )


@lru_cache(maxsize=None)
def _main(argv: tuple[str, ...], fleet_text: str, tmp: str) -> tuple[int, str, str]:
    tmp_path = Path(tmp)
    path = tmp_path / "fleet.yaml"
    path.write_text(fleet_text)
    done = run(sys.executable, tmp_path, path, *argv)
    return done.returncode, done.stdout, done.stderr


def beside_main(python, tmp_path, fleet_path, *argv) -> tuple[int, str, str]:
    """The command's exit code, stdout and stderr under ``python``, asserted the main interpreter's."""
    done = run(python, tmp_path, fleet_path, *argv)
    main_dir = tmp_path.parent / f"main-{tmp_path.name[:-1]}"  # one for the test's every Python
    main_dir.mkdir(exist_ok=True)
    (main_dir / "id_fleet").write_bytes((tmp_path / "id_fleet").read_bytes())
    expected = _main(tuple(argv), fleet_path.read_text().replace(str(tmp_path), str(main_dir)), str(main_dir))
    said = (done.returncode, done.stdout.replace(str(tmp_path), "TMP"), done.stderr.replace(str(tmp_path), "TMP"))
    code, stdout, stderr = expected
    assert said[:2] == (code, stdout.replace(str(main_dir), "TMP"))
    assert _lines(said[2]) == _lines(stderr.replace(str(main_dir), "TMP"))
    return said


def _lines(stderr: str) -> list[str]:
    """Lines in any order, without the count of hosts answered so far: hosts answer in parallel."""
    return sorted(re.sub(r" \(\d+/\d+\)$", "", line) for line in stderr.splitlines())


def test_the_readme_s_install_gives_the_command(python):
    said = subprocess.run([str(python.parent / "robotfleet"), "--version"], capture_output=True, text=True)
    assert said.returncode == 0 and said.stdout.startswith("robotfleet "), said.stderr
    version = subprocess.run([str(python), "-c", "import sys; print(sys.version_info[:2])"], capture_output=True)
    assert version.stdout.decode().strip() != str(sys.version_info[:2])  # another Python than the main one


def test_the_fleet_check_refuses_bad_data_in_one_line_each(python, tmp_path):
    path = fleet(tmp_path, {"robot1": {"address": "10.0.0.1", "docker_usres": ["ops"]}, "robot2": BAD_COMPOSE})
    code, _, stderr = beside_main(python, tmp_path, path, "-m", "robotfleet", "status", "inventories/robots.py")
    assert code == 2
    assert "robot1.docker_usres: unknown setting (did you mean 'docker_users'?)" in stderr
    assert "robot2.payload_services.payload.restatr" in stderr, stderr  # the Compose schema's refusal


def test_the_inventory_shows_the_fleet_it_reads(python, tmp_path):
    path = fleet(tmp_path, {"robot1": {"address": "10.0.0.1", "docker_users": ["ops"]}})
    argv = ("-m", "robotfleet", "inventory", "inventories/robots.py", "--host", "robot1")
    code, stdout, _ = beside_main(python, tmp_path, path, *argv)
    assert code == 0 and "docker_users" in stdout and "10.0.0.1" in stdout


def test_status_names_each_robot_it_cannot_reach(python, tmp_path):
    path = fleet(tmp_path, {f"robot{n}": {"address": "127.0.0.1", "ssh_port": sshserver.closed_port()} for n in (1, 2)})
    code, stdout, stderr = beside_main(python, tmp_path, path, "-m", "robotfleet", "status", "inventories/robots.py")
    assert code == 3 and stderr.count("unreachable:") == 2, stderr
    *rows, summary = stdout.splitlines()[1:]
    assert [line.split()[:2] for line in rows] == [["robot1", "no:"], ["robot2", "no:"]], stdout
    assert summary == "2 unreachable", stdout


def test_pyinfra_dry_plans_the_deploy_and_names_the_reason(python, tmp_path):
    output = dry_run(tmp_path, str(python))
    assert "@fake/good" in output.split("--> Detected changes", 1)[1]  # the other robot's plan


def test_ubuntu_20_04_s_python_is_refused_in_one_line_that_says_what_to_do(tmp_path):
    """pip itself checks requires-python only after resolving every dependency: on 3.8 it ended on
    "No matching distribution found for tuf<8,>=7" (robotfleet/build_backend.py)."""
    python = pythons.require("3.8")
    subprocess.run([str(python), "-m", "venv", "--without-pip", str(tmp_path / "venv")], check=True)
    refused = subprocess.run(
        [sys.executable, "-m", "pip", "--python", str(tmp_path / "venv" / "bin" / "python"), "install"]
        + ["--disable-pip-version-check", "--no-index", "--no-build-isolation", "-e", str(ROOT)],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "PIP_CONFIG_FILE": os.devnull},
    )
    assert refused.returncode == 1
    line = (
        "robot-fleet-provisioner needs Python 3.10 or later (pyinfra 3), and this is Python 3.8: "
        "make the venv with a newer Python (docs/guides/install.md, Ubuntu 20.04)"
    )
    assert [said.strip() for said in refused.stderr.splitlines() if "robot-fleet-provisioner" in said] == [line]
    assert "No matching distribution" not in refused.stderr
