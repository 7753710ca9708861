"""Fixtures of every layer.

Some modules import ssl when they are imported (the lab's through docker,
the payload role's registry client through urllib); importing them at
collection time, before pyinfra's gevent patches ssl in other test modules,
makes gevent warn.  So each of these fixtures imports its module when a
test runs."""

import importlib

import pytest


def _imported_when_used(name: str, module: str):
    @pytest.fixture(name=name)
    def fixture():
        return importlib.import_module(module)

    return fixture


engine = _imported_when_used("engine", "tests.lab.engine")
hostimage = _imported_when_used("hostimage", "tests.lab.hostimage")
hosts = _imported_when_used("hosts", "tests.lab.hosts")
services = _imported_when_used("services", "tests.lab.services")
state = _imported_when_used("state", "tests.lab.state")
emulation = _imported_when_used("emulation", "tests.lab.emulation")
registry = _imported_when_used("registry", "roles.payload.registry")
push = _imported_when_used("push", "roles.payload.push")
