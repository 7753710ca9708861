"""The registry client's pure rules (roles/payload/registry.py): which
registries get plain HTTP, repository paths, a token challenge read; its
talks with a registry are in tests/integration/test_registry.py."""


def test_plain_http_only_for_this_machine_or_a_registry_the_fleet_lists_insecure(registry):
    assert registry.base_url("127.0.0.1:25000") == "http://127.0.0.1:25000"
    assert registry.base_url("localhost:5000") == "http://localhost:5000"
    assert registry.base_url("[::1]:5000") == "http://[::1]:5000"
    assert registry.base_url("lab-services:5000", ["lab-services:5000"]) == "http://lab-services:5000"
    assert registry.base_url("lab-services:5000") == "https://lab-services:5000"
    assert registry.base_url("registry.example.com") == "https://registry.example.com"
    assert registry.base_url("docker.io") == "https://registry-1.docker.io"


def test_repository_paths_on_their_registry(registry):
    assert registry.path_of("reg.lan:5000/ros/payload") == "ros/payload"
    assert registry.path_of("ros/payload") == "ros/payload"
    assert registry.path_of("ubuntu") == "library/ubuntu"
    assert registry.path_of("docker.io/ubuntu") == "library/ubuntu"
    assert registry.path_of("index.docker.io/ubuntu") == "library/ubuntu"
    assert registry.path_of("docker.io/ros/payload") == "ros/payload"


def test_a_one_part_name_is_under_library_on_docker_hub_only(registry):
    """Docker adds library/ to a one-part name on Docker Hub; any other
    registry serves the name as it is (registry.lan:5000/payload:1)."""
    assert registry.path_of("registry.lan:5000/payload") == "payload"
    assert registry.path_of("localhost:5000/payload") == "payload"
    assert registry.path_of("127.0.0.1:5000/payload") == "payload"
    assert registry.path_of("ghcr.io/payload") == "payload"


def test_a_bearer_challenge_is_read(registry):
    assert registry.challenge(
        'Bearer realm="https://auth.docker.io/token",service="registry.docker.io",'
        'scope="repository:library/ubuntu:pull"'
    ) == (
        "bearer",
        {
            "realm": "https://auth.docker.io/token",
            "service": "registry.docker.io",
            "scope": "repository:library/ubuntu:pull",
        },
    )
