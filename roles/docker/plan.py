"""Pure decisions of the docker role: what to install from which repository,
computed from host facts and data, so they test without a host."""

from __future__ import annotations

import json

SUPPORTED = {
    "ubuntu": {"focal": "20.04", "jammy": "22.04", "noble": "24.04"},
    "debian": {"bookworm": "12", "trixie": "13"},
}
ARCHITECTURES = ("amd64", "arm64")
# The distribution's own engine + compose v2 (docker_source: distro).
DISTRO_PACKAGES = {
    ("ubuntu", "jammy"): ["docker.io", "docker-compose-v2"],
    ("ubuntu", "noble"): ["docker.io", "docker-compose-v2"],
    ("debian", "trixie"): ["docker.io", "docker-compose"],
}
PINNED_BY_VERSION = ("docker-ce", "docker-ce-cli")


class PlanError(Exception):
    """The host cannot get what its data asks for; fails that host only."""


def distribution(os_release: dict) -> str:
    """Docker's repository for this host: "ubuntu" or "debian" (derivatives
    such as Mint map through ID_LIKE)."""
    ident = os_release.get("id", "")
    like = os_release.get("id_like", "").split()
    if ident == "ubuntu" or "ubuntu" in like:
        return "ubuntu"
    if ident == "debian" or "debian" in like:
        return "debian"
    name = os_release.get("pretty_name") or ident or "unknown OS"
    raise PlanError(f"{name} is not Ubuntu or Debian; Docker's apt repository does not serve it")


def suite(os_release: dict) -> str:
    """The apt suite: UBUNTU_CODENAME (set on derivatives) else VERSION_CODENAME."""
    dist = distribution(os_release)
    codename = (
        os_release.get("ubuntu_codename") if dist == "ubuntu" else None
    ) or os_release.get("version_codename")
    if not codename:
        raise PlanError("cannot tell the release codename from /etc/os-release")
    if codename not in SUPPORTED[dist]:
        known = ", ".join(f"{dist} {v} ({k})" for k, v in SUPPORTED[dist].items())
        raise PlanError(f"{dist} {codename} is not supported; supported: {known}")
    return codename


def architecture(dpkg_arch: str) -> str:
    if dpkg_arch not in ARCHITECTURES:
        raise PlanError(f"architecture {dpkg_arch or 'unknown'} is not supported (supported: amd64, arm64)")
    return dpkg_arch


def repo_uri(repo_url: str, dist: str) -> str:
    return f"{repo_url.rstrip('/')}/{dist}"


def key_url(data_key_url: str | None, repo_url: str, dist: str) -> str:
    return data_key_url or f"{repo_uri(repo_url, dist)}/gpg"


def sources_text(uri: str, suite_name: str, channel: str, arch: str, key_path: str) -> str:
    """deb822 source, as Docker documents it."""
    return (
        "# Managed by the robot fleet provisioner (roles/docker).\n"
        "Types: deb\n"
        f"URIs: {uri}\n"
        f"Suites: {suite_name}\n"
        f"Components: {channel}\n"
        f"Architectures: {arch}\n"
        f"Signed-By: {key_path}\n"
    )


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


def daemon_json(options: dict, mirrors: list[str], insecure: list[str]) -> str:
    merged = dict(options)
    for key, extra in (("registry-mirrors", mirrors), ("insecure-registries", insecure)):
        if extra:
            current = list(merged.get(key, []))
            merged[key] = current + [item for item in extra if item not in current]
    return json.dumps(merged, indent=2, sort_keys=True) + "\n"


def normalise_fingerprint(value: str | None) -> str | None:
    return value.replace(" ", "").upper() if value else None
