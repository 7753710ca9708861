"""state.json round trip and its exact keys."""

import pytest


def sample(prefix="t"):
    return {
        "prefix": prefix, "ssh_key": "/k", "known_hosts": "/kh", "ssh_user": "ops",
        "hosts": [{"name": "robot1", "group": "robots", "container": f"{prefix}-robot1", "port": 22001}],
        "services_host": f"{prefix}-services", "apt_proxy": f"http://{prefix}-services:3142",
        "registry": f"{prefix}-services:5000", "registry_local": "127.0.0.1:25000",
        "mirror_url": f"http://{prefix}-services:8080/linux", "mirror_dir": "/m",
    }


def test_round_trip(state, tmp_path):
    path = state.save(sample(), root=tmp_path)
    assert path == tmp_path / "t" / "state.json"
    assert state.load("t", root=tmp_path) == sample()


def test_keys_are_exactly_the_contract(state, tmp_path):
    with pytest.raises(ValueError):
        state.save(dict(sample(), extra=1), root=tmp_path)
    incomplete = sample()
    del incomplete["registry"]
    with pytest.raises(ValueError):
        state.save(incomplete, root=tmp_path)


def test_load_of_a_lab_that_is_not_up_says_how_to_start_it(state, tmp_path):
    from tests.lab.engine import LabError

    with pytest.raises(LabError, match="python3 -m tests.lab up --prefix nope"):
        state.load("nope", root=tmp_path)


def test_prefix_comes_from_the_environment(state, monkeypatch):
    monkeypatch.delenv("ROBOT_LAB_PREFIX", raising=False)
    assert state.lab_prefix() == "lab"
    monkeypatch.setenv("ROBOT_LAB_PREFIX", "e2e")
    assert state.lab_prefix() == "e2e"
