"""The integration layer: tests that start processes on this machine (sh,
gpg, apt, systemd-analyze, pyinfra's and robotfleet's CLI, payloadctl as the
robots run it, virtual environments) or talk over sockets on 127.0.0.1 (SSH
servers, a registry).  No Docker engine, no simulated fleet: that is the
end-to-end layer's."""

import pytest

from tests.integration import imagestore, mediaworld, publishsite


def pytest_collection_modifyitems(items):
    for item in items:
        if "/integration/" in str(item.fspath):
            item.add_marker(pytest.mark.integration)


@pytest.fixture
def client_key(tmp_path):
    """The operator's SSH key, at tmp_path/id_fleet, for the SSH servers here
    (tests/integration/sshserver.py)."""
    import paramiko

    key = paramiko.ECDSAKey.generate()
    key.write_private_key_file(str(tmp_path / "id_fleet"))
    return key


@pytest.fixture(autouse=True, scope="session")
def _no_gpg_agent_left_running(tmp_path_factory):
    """The key tests make real keyrings; gpg starts an agent for each."""
    yield
    from tests import armor

    armor.stop_agents(tmp_path_factory.getbasetemp())


@pytest.fixture(scope="module")
def helper(tmp_path_factory):
    """payloadctl exactly as it is installed on a robot."""
    from roles.payload import installed_files as payload

    path = tmp_path_factory.mktemp("helper") / "payloadctl"
    path.write_bytes(payload.helper_bytes())
    path.chmod(0o755)
    return str(path)


@pytest.fixture
def robot(tmp_path, helper):
    """A robot of payloadctl's tests (tests/integration/payloadrobot.py) running reg/ros/payload:1.0."""
    from tests.integration.payloadrobot import FakeRobot

    robot = FakeRobot(tmp_path, helper)
    robot.image("reg/ros/payload:1.0")
    robot.release("r1", "reg/ros/payload:1.0")
    robot.releases.point("current", "r1")
    robot.running("reg/ros/payload:1.0")
    return robot


@pytest.fixture
def platform_registry():
    """A registry on 127.0.0.1 with one image for amd64 and arm64 under one tag
    (tests/integration/imagestore.py): (address, store, the blobs fetched)."""
    yield from imagestore.serve()


@pytest.fixture(scope="module")
def registry():
    """An OCI registry on 127.0.0.1 answering manifest requests (tests/unit/pullkit.py's Registry)."""
    from tests.unit import pullkit

    server = pullkit.Registry()
    yield server
    server.close()


@pytest.fixture
def site(tmp_path, registry):
    """An operator's deploy repository for the pull commands (tests/integration/publishsite.py):
    a dict of its checkout, remotes, keys and a robot's directory.  test_pull_enroll.py has its own."""
    return publishsite.site(tmp_path, registry)


@pytest.fixture
def image_registry(platform_registry):
    """platform_registry, its index also served by its digest (as registries do)."""
    return mediaworld.by_its_digest(platform_registry)


@pytest.fixture
def docker(tmp_path, monkeypatch):
    """A `docker` for the pull agent that records its calls (tests/integration/mediaworld.py):
    the calls made so far."""
    return mediaworld.fake_docker(tmp_path, monkeypatch)
