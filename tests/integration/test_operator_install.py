"""The operators' install (README, Install for operators) is the one way:
an editable install from the checkout renders everything from any directory;
a non-editable install (a wheel) refuses to load with one clear line."""

import re
import shutil
import site
import subprocess
import sys
import venv
import zipfile
from pathlib import Path

import pytest

from tests.fixtures import ROOT

NOT_COPIED = shutil.ignore_patterns(".git", ".lab", ".venv", "__pycache__", "*.egg-info", "build", ".pytest_cache")

RENDER = """
from robotfleet import deploy_roles  # puts its checkout first on sys.path: roles/ is the checkout's
from roles import udev, x11
from roles.payload import installed_files as payload
defaults = {group: deploy_roles.group_data(group) for group in ("all", "robots", "laptops")}
class Data(dict):
    __getattr__ = dict.__getitem__
robot = Data({**defaults["all"], **defaults["robots"], "payload_image": "r.lan/p:1"})
laptop = Data({**defaults["all"], **defaults["laptops"], "x11_user": "alice"})
print(payload.unit_text(robot, ["/dev/robot/lidar"]).splitlines()[2])
print(x11.cookie_script(laptop).count("nmerge"))
print(sorted(udev.vendor_rules(robot)))
print((x11.HERE / "robot-x11-cookie.desktop").is_file(), (x11.HERE / "90robot-x11-cookie").is_file())
"""


def run(*args, cwd):
    return subprocess.run(args, cwd=cwd, capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def checkout(tmp_path_factory):
    """A copy of the checkout, as an operator would clone it."""
    copy = tmp_path_factory.mktemp("operator") / "robot-fleet"
    shutil.copytree(ROOT, copy, ignore=NOT_COPIED)
    return copy


@pytest.fixture(scope="module")
def venv_python(tmp_path_factory):
    """An empty venv whose dependencies are the running interpreter's
    site-packages (the unit layer is offline; the README's commands fetch
    them from PyPI).  They are listed in a .pth, so their own .pth files (an
    editable install of this checkout) are not processed."""
    env = tmp_path_factory.mktemp("venv") / "venv"
    venv.create(env, with_pip=False)  # this interpreter's pip installs into it (--python)
    python = env / "bin" / "python"
    purelib = run(
        str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])", cwd=env
    ).stdout.strip()
    Path(purelib, "deps-of-the-test-runner.pth").write_text("\n".join(site.getsitepackages()) + "\n")
    return python


def pip_install(python, *args, cwd):
    result = run(
        sys.executable,
        "-m",
        "pip",
        "--python",
        str(python),
        "install",
        "-q",
        "--no-deps",
        "--no-build-isolation",
        *args,
        cwd=cwd,
    )
    assert result.returncode == 0, result.stderr[-2000:]


def test_a_wheel_installs_only_robotfleet_and_refuses_in_one_line(checkout, venv_python, tmp_path):
    built = run(
        sys.executable,
        "-m",
        "pip",
        "wheel",
        "-q",
        "--no-deps",
        "--no-build-isolation",
        "-w",
        str(tmp_path),
        str(checkout),
        cwd=tmp_path,
    )
    assert built.returncode == 0, built.stderr[-2000:]
    wheel = next(tmp_path.glob("*.whl"))
    with zipfile.ZipFile(wheel) as archive:
        top = {name.split("/")[0] for name in archive.namelist() if not name.split("/")[0].endswith(".dist-info")}
    assert top == {"robotfleet"}, top  # no `engine`, no `roles` in site-packages
    pip_install(venv_python, str(wheel), cwd=tmp_path)
    script = venv_python.parent / "robotfleet"
    for argv in (
        [str(script), "--help"],
        [str(script), "status", "x.py"],
        [str(venv_python), "-c", "import robotfleet"],
    ):
        result = run(*argv, cwd=tmp_path)
        assert result.returncode == 2, (argv, result.stderr)
        assert result.stderr.strip().splitlines() == [
            f"robotfleet: {result.stderr.split()[1]} is not in a checkout of the robot fleet provisioner "
            "(no deploy.py beside it); it runs from its checkout: in the checkout, "
            "python3 -m venv .venv && .venv/bin/pip install -e .  (README: Install for operators)"
        ], argv
        assert "/site-packages/robotfleet" in result.stderr


def test_editable_install_renders_from_any_directory(checkout, venv_python, tmp_path):
    pip_install(venv_python, "-e", str(checkout), cwd=checkout)
    result = run(str(venv_python), "-c", RENDER, cwd=tmp_path)
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.splitlines() == [
        "Description=Robot payload robot-payload (docker compose, current release)",
        "1",
        "['/etc/udev/rules.d/60-usb-serial-low-latency.rules']",
        "True True",
    ]
    # roles/ is not installed: only the checkout's, found through robotfleet
    alone = run(str(venv_python), "-c", "import roles", cwd=tmp_path)
    assert "No module named 'roles'" in alone.stderr
    imported = run(str(venv_python), "-c", "import robotfleet, roles; print(roles.__file__)", cwd=tmp_path)
    assert imported.stdout.strip() == str(checkout / "roles" / "__init__.py")
    assert run(str(venv_python.parent / "robotfleet"), "--version", cwd=tmp_path).stdout.startswith("robotfleet ")


def test_readme_installs_operators_before_the_lab_and_without_the_lab_setup():
    """README's "Install for operators" (and docs/guides/install.md, docs/guides/laptops.md)
    install with pip into .venv, never with the lab's .ci/setup; the lab is
    a page of docs/, after the operator's path."""
    text = (ROOT / "README.md").read_text()
    titles = re.findall(r"^## (.+)$", text, re.M)
    assert titles.index("Install for operators") < titles.index("Describing a fleet")
    assert "The simulated fleet" not in titles and "](docs/guides/lab.md)" in text.split("\n## More\n", 1)[1]
    section = text.split("## Install for operators", 1)[1].split("\n## ", 1)[0]
    pages = [section, *((ROOT / "docs" / "guides" / name).read_text() for name in ("install.md", "laptops.md"))]
    for page in pages:
        commands = [line.strip() for line in page.splitlines() if line.startswith("    ")]
        assert not [
            c
            for c in commands
            if ".ci/setup" in c or c.startswith("sudo pip") or "pip install ." in c.replace("-e .", "")
        ]
    for page in pages[:2]:
        commands = [line.strip() for line in page.splitlines() if line.startswith("    ")]
        assert "python3 -m venv .venv" in commands
        assert any(c.startswith(".venv/bin/pip install -e .") for c in commands)
