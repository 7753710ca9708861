"""Pure decisions of the docker role: what to install from which repository,
computed from host facts and data, so they test without a host."""

from __future__ import annotations

import json

from robotfleet.host import aptrepo, platform
from robotfleet.host.platform import PlanError, architecture  # noqa: F401 (the role's plan names them)

SUPPORTED = {
    "ubuntu": {"focal": "20.04", "jammy": "22.04", "noble": "24.04"},
    "debian": {"bookworm": "12", "trixie": "13"},
}
# The distribution's own engine + compose v2 (docker_source: distro).
DISTRO_PACKAGES = {
    ("ubuntu", "jammy"): ["docker.io", "docker-compose-v2"],
    ("ubuntu", "noble"): ["docker.io", "docker-compose-v2"],
    ("debian", "trixie"): ["docker.io", "docker-compose"],
}
PINNED_BY_VERSION = ("docker-ce", "docker-ce-cli")


def distribution(os_release: dict) -> str:
    """Docker's repository for this host: "ubuntu" or "debian"."""
    try:
        return platform.distribution(os_release)
    except PlanError as error:
        raise PlanError(f"{error}; Docker's apt repository does not serve it") from None


def suite(os_release: dict) -> str:
    dist = distribution(os_release)
    codename = platform.codename(os_release)
    if codename not in SUPPORTED[dist]:
        known = ", ".join(f"{dist} {v} ({k})" for k, v in SUPPORTED[dist].items())
        raise PlanError(f"{dist} {codename} is not supported; supported: {known}")
    return codename


def repo_uri(repo_url: str, dist: str) -> str:
    return f"{repo_url.rstrip('/')}/{dist}"


def key_url(data_key_url: str | None, repo_url: str, dist: str) -> str:
    return data_key_url or f"{repo_uri(repo_url, dist)}/gpg"


def sources_text(uri: str, suite_name: str, channel: str, arch: str, key_path: str) -> str:
    """deb822 source, as Docker documents it."""
    return aptrepo.deb822("roles/docker", uri, suite_name, key_path, components=channel, architectures=arch)


def package_versions(packages: list[str], version: str | None) -> dict[str, str]:
    if not version:
        return {}
    return {name: version for name in packages if name in PINNED_BY_VERSION}


def obsolete_to_remove(obsolete: list[str], installed: dict[str, str]) -> list[str]:
    """Conflicting packages to remove: only installed ones, only while Docker CE is not."""
    if "docker-ce" in installed:
        return []
    return [name for name in obsolete if name in installed]


def distro_packages(os_release: dict, override: list[str] | None) -> list[str]:
    if override:
        return list(override)
    dist = distribution(os_release)
    codename = suite(os_release)
    packages = DISTRO_PACKAGES.get((dist, codename))
    if not packages:
        raise PlanError(
            f"{dist} {codename} has no compose v2 package of its own; "
            "use docker_source: docker (or set docker_distro_packages)"
        )
    return packages


def daemon_json(options: dict, keys: dict) -> str:
    """daemon.json: ``options``, then each of ``keys`` (daemon.json key ->
    value): a list merged into the option's list, any other value but None
    in its place."""
    merged = dict(options)
    for key, value in keys.items():
        if isinstance(value, list):
            if value:
                current = list(merged.get(key, []))
                merged[key] = current + [item for item in value if item not in current]
        elif value is not None:
            merged[key] = value
    return json.dumps(merged, indent=2, sort_keys=True) + "\n"
