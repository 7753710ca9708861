"""Fixtures for the lab's unit tests.

The lab modules import docker (and so ssl); importing them at collection
time, before pyinfra's gevent patches ssl in other test modules, makes gevent
warn.  So each fixture imports its module when a test runs.
"""

import importlib

import pytest


def _lab_module(name: str):
    @pytest.fixture(name=name)
    def fixture():
        return importlib.import_module(f"tests.lab.{name}")

    return fixture


engine = _lab_module("engine")
hostimage = _lab_module("hostimage")
hosts = _lab_module("hosts")
services = _lab_module("services")
state = _lab_module("state")
emulation = _lab_module("emulation")


@pytest.fixture(autouse=True, scope="session")
def _no_gpg_agent_left_running(tmp_path_factory):
    """The key tests make real keyrings; gpg starts an agent for each."""
    yield
    from tests import armor

    armor.stop_agents(tmp_path_factory.getbasetemp())
