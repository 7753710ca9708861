"""The wheelhouse robots install from (robotfleet/pull/operator/wheels.py): the
robot's platform key (robotfleet/pull/protocol/platforms.py), and binary wheels for another machine fetched from
PyPI with pip (a small requirement)."""

import os

import pytest

from robotfleet.pull.operator import wheels
from robotfleet.pull.protocol import platforms


def test_platform_keys():
    assert platforms.platform_key((3, 13), "x86_64") == "cp313-x86_64"
    assert platforms.platform_key((3, 11), "arm64") == "cp311-aarch64"
    assert platforms.parse_platform("cp311-aarch64") == ("3.11", "aarch64")
    with pytest.raises(ValueError, match="platform 'py3-any': expected cp<python version>-<machine>"):
        platforms.parse_platform("py3-any")


def test_requirements_come_from_the_commits_pyproject():
    assert wheels.requirements_of(b'[project]\nname = "x"\ndependencies = ["a>=1", "b"]\n') == ["a>=1", "b"]
    with pytest.raises(wheels.WheelError, match="pyproject.toml: no \\[project\\] dependencies"):
        wheels.requirements_of(b"[tool.x]\n")


def test_binary_wheels_for_another_machine_and_python(tmp_path):
    found = wheels.build_wheelhouse(["MarkupSafe==2.1.5"], "cp311-aarch64", tmp_path)
    assert [p.name for p in found] == ["MarkupSafe-2.1.5-cp311-cp311-manylinux_2_17_aarch64.manylinux2014_aarch64.whl"]
    # a second build finds them in the cache and names only what this set resolved to
    (tmp_path / "cp311-aarch64" / "stale-0.1-py3-none-any.whl").write_bytes(b"PK")
    assert wheels.build_wheelhouse(["MarkupSafe==2.1.5"], "cp311-aarch64", tmp_path) == found
    other = wheels.build_wheelhouse(["MarkupSafe==2.1.4"], "cp311-aarch64", tmp_path)
    assert [p.name for p in other] == [found[0].name.replace("2.1.5", "2.1.4")]


def test_a_requirement_without_a_wheel_is_one_line(tmp_path):
    with pytest.raises(wheels.WheelError) as caught:
        wheels.build_wheelhouse(["robotfleet-no-such-package-xyz==1"], "cp313-x86_64", tmp_path)
    assert str(caught.value).startswith("wheels for cp313-x86_64: ")
    assert "\n" not in str(caught.value)


def test_a_cache_holding_every_requirement_is_used_without_the_index(tmp_path, monkeypatch):
    """publish spent 20-60 s resolving against the index with every wheel cached."""
    monkeypatch.setenv("PIP_CONFIG_FILE", os.devnull)  # only the index given here (no local mirror)
    monkeypatch.delenv("PIP_FIND_LINKS", raising=False)
    found = wheels.build_wheelhouse(["MarkupSafe==2.1.5", "six"], "cp311-aarch64", tmp_path)
    nowhere = "http://127.0.0.1:9/simple"  # nothing listens: any question to the index fails
    assert wheels.build_wheelhouse(["MarkupSafe==2.1.5", "six"], "cp311-aarch64", tmp_path, index_url=nowhere) == found
    # a requirement the cache lacks goes to the index (which here cannot answer) ...
    with pytest.raises(wheels.WheelError, match="wheels for cp311-aarch64: "):
        wheels.build_wheelhouse(["MarkupSafe==2.1.4"], "cp311-aarch64", tmp_path, index_url=nowhere)
    # ... and so does everything when asked to refresh
    with pytest.raises(wheels.WheelError):
        wheels.build_wheelhouse(["six"], "cp311-aarch64", tmp_path, index_url=nowhere, refresh=True)


def test_a_robot_s_wheels_follow_the_markers_of_its_own_python(tmp_path):
    """pip evaluates markers for the interpreter it runs in: a 3.10 robot's wheelhouse fetched from a newer
    operator lacked what pip on 3.10 installs (pyinfra's typing-extensions; python_version < '3.11')."""
    wanted = ["six==1.17.0", "tomli==2.0.1; python_version < '3.11'"]
    older = wheels.build_wheelhouse(wanted, "cp310-x86_64", tmp_path)
    assert [p.name for p in older] == ["six-1.17.0-py2.py3-none-any.whl", "tomli-2.0.1-py3-none-any.whl"]
    newer = wheels.build_wheelhouse(wanted, "cp313-x86_64", tmp_path)
    assert [p.name for p in newer] == ["six-1.17.0-py2.py3-none-any.whl"]


def test_a_python_too_old_for_pull_mode_gets_no_wheels_and_one_line(tmp_path):
    with pytest.raises(wheels.WheelError) as caught:
        wheels.build_wheelhouse(["six"], "cp38-x86_64", tmp_path)
    assert str(caught.value) == (
        "wheels for cp38-x86_64: a robot's python3 3.8 is too old for pull mode (the robot runs pyinfra 3, which "
        "needs Python 3.10 or later): provision it by push (pull_enabled: false), or give it a python3 of 3.10 "
        "or later"
    )
    assert not (tmp_path / "cp38-x86_64").exists()  # pip was not asked


def test_a_package_without_a_wheel_for_the_platform_is_named_with_it(tmp_path):
    """PyYAML publishes no wheel for 32-bit ARM: a robot there cannot be given one."""
    with pytest.raises(wheels.WheelError) as caught:
        wheels.build_wheelhouse(["pyyaml==6.0.2"], "cp313-armv7l", tmp_path)
    said = str(caught.value)
    assert said.startswith(
        "wheels for cp313-armv7l: no wheel of pyyaml==6.0.2 for CPython 3.13 on armv7l (robots install binary wheels "
        "only) (pip's log: "
    ), said
