"""What a host is, from its snapshot: distribution, release, architecture.

Pure, so a role's plan is tested against Ubuntu and Debian readings without
a host.  A role that cannot serve a host raises PlanError: that host fails,
with one line, before anything is installed; the others go on."""

from __future__ import annotations

ARCHITECTURES = ("amd64", "arm64")


class PlanError(Exception):
    """The host cannot get what its data asks for; fails that host only."""


def distribution(os_release: dict) -> str:
    """ "ubuntu" or "debian" (derivatives such as Mint map through ID_LIKE)."""
    ident = os_release.get("id", "")
    like = os_release.get("id_like", "").split()
    if ident == "ubuntu" or "ubuntu" in like:
        return "ubuntu"
    if ident == "debian" or "debian" in like:
        return "debian"
    name = os_release.get("pretty_name") or ident or "unknown OS"
    raise PlanError(f"{name} is not Ubuntu or Debian")


def codename(os_release: dict) -> str:
    """The apt suite: UBUNTU_CODENAME (set on derivatives) else VERSION_CODENAME."""
    dist = distribution(os_release)
    name = (os_release.get("ubuntu_codename") if dist == "ubuntu" else None) or os_release.get("version_codename")
    if not name:
        raise PlanError("cannot tell the release codename from /etc/os-release")
    return name


def architecture(dpkg_arch: str) -> str:
    if dpkg_arch not in ARCHITECTURES:
        raise PlanError(
            f"architecture {dpkg_arch or 'unknown'} is not supported (supported: {', '.join(ARCHITECTURES)})"
        )
    return dpkg_arch
