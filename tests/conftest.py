"""Fixtures of every layer.

Some modules import ssl when they are imported (the lab's through docker,
the payload role's registry client through urllib); importing them at
collection time, before pyinfra's gevent patches ssl in other test modules,
makes gevent warn.  So each of these fixtures imports its module when a
test runs."""

import importlib
import os

import pytest

from tests.fixtures import gevent_os_patched


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
image_transfer = _imported_when_used("image_transfer", "roles.payload.image_transfer")


# Once pyinfra's CLI is imported, gevent (>= 25.8.1) patches ``os.close`` to
# close a directory or a pipe only when gevent's loop next runs.  Tests that
# run no greenlet (temporary directories removed, files fsynced) left
# thousands of descriptors open, and CI's run ended on "Too many open files".


@pytest.fixture(autouse=True)
def _deferred_closes_done():
    """The loop runs once after each test, as it does all the time in a
    pyinfra run (a test that closes thousands by itself, test_lifecycle,
    takes os.close as it was)."""
    yield
    if gevent_os_patched():
        import gevent

        gevent.idle()


@pytest.hookimpl(tryfirst=True)
def pytest_sessionfinish(session, exitstatus):
    """pytest's own cleanup removes old temporary directories with
    shutil.rmtree, which opens and closes every directory while no greenlet
    runs: the tests being over, os.close is gevent's no more."""
    monkey = gevent_os_patched()
    if monkey:
        os.close = monkey.get_original("os", "close")


@pytest.fixture(scope="module")
def sent_to_a_fresh_robot():
    """The files a fresh robot is sent, by path (compose.yaml: as payloadctl
    writes it); tests/unit/test_generated_files.py compares them with their
    golden copies, tests/integration/test_generated_files.py has systemd
    check the unit."""
    import json

    from roles.payload.payloadctl.releases import compose_yaml, release_compose
    from tests.unit.harness import ROBOT, find, fresh_host, plan, written_files

    commands = plan(
        {
            "robot1": (
                "robots",
                {
                    **ROBOT,
                    "ssh_hostname": "10.20.0.11",
                    "docker_registry_mirrors": ["https://mirror.lan"],
                    "docker_insecure_registries": ["registry.lan:5000"],
                },
                fresh_host("debian-13"),
            )
        }
    )["robot1"]
    files = written_files(commands)
    release = find(commands, "payloadctl apply")
    assert len(release) == 1
    files["compose.yaml"] = compose_yaml(release_compose(json.loads(release[0].stdin)["spec"]["compose"]))
    return files
