"""Image platforms (pure): what a robot is, what an image is built for, the
variant of a multi-platform image a robot gets, and the one line that
refuses the wrong one.  The deploy side (push, the settings) and the robot
side (apply) use the same rules.

Architectures have three spellings: Debian's (dpkg --print-architecture:
amd64, arm64, armhf), the kernel's (uname -m: x86_64, aarch64, armv7l) and
Go's, which Docker and the OCI image spec use (amd64, arm64, arm + variant).
Everything here compares Go's.
"""

import re

_GO_ARCH = {
    "x86_64": "amd64",
    "amd64": "amd64",
    "aarch64": "arm64",
    "arm64": "arm64",
    "armhf": "arm",
    "armel": "arm",
    "armv7l": "arm",
    "armv6l": "arm",
    "arm": "arm",
    "i386": "386",
    "i686": "386",
    "386": "386",
    "ppc64el": "ppc64le",
    "ppc64le": "ppc64le",
    "s390x": "s390x",
    "riscv64": "riscv64",
}
_PLATFORM = re.compile(r"([a-z0-9]+)/([a-z0-9_]+)(?:/([a-z0-9]+))?")

INDEX_TYPES = (
    "application/vnd.oci.image.index.v1+json",
    "application/vnd.docker.distribution.manifest.list.v2+json",
)
MANIFEST_TYPES = (
    "application/vnd.oci.image.manifest.v1+json",
    "application/vnd.docker.distribution.manifest.v2+json",
)


def go_arch(name):
    """An architecture as Docker names it ("aarch64" -> "arm64"); unknown
    names are returned as they are."""
    return _GO_ARCH.get((name or "").strip(), (name or "").strip())


def parse(text):
    """ "linux/arm64" or "linux/arm/v7" -> {"os", "architecture"[, "variant"]};
    ValueError with the reason otherwise."""
    match = _PLATFORM.fullmatch(text) if isinstance(text, str) else None
    if not match:
        raise ValueError("expected os/architecture[/variant] like linux/arm64, got {!r}".format(text))
    found = {"os": match.group(1), "architecture": match.group(2)}
    if match.group(3):
        found["variant"] = match.group(3)
    return found


def text(platform):
    """{"os": "linux", "architecture": "arm64", "variant": "v8"} -> "linux/arm64/v8"."""
    parts = [platform.get("os") or "?", platform.get("architecture") or "?"]
    if platform.get("variant"):
        parts.append(platform["variant"])
    return "/".join(parts)


def robot_platform(arch):
    """The platform of a robot whose architecture is ``arch`` (any spelling)."""
    return {"os": "linux", "architecture": go_arch(arch)}


def matches(robot_arch, platform):
    """Whether a robot of ``robot_arch`` runs images built for ``platform``.
    Variants (arm64's v8, arm's v6/v7) are not compared: Docker itself picks
    among them."""
    return platform.get("os", "linux") == "linux" and go_arch(platform.get("architecture")) == go_arch(robot_arch)


def refusal(robot, robot_arch, image, platforms, where=""):
    """The one line that refuses an image the robot cannot run."""
    shown = ", ".join(platforms) or "of no platform"
    only = " only" if len(platforms) == 1 else ""
    return "{} is {} but image {} is {}{}{}: refused before anything switched".format(
        robot, text(robot_platform(robot_arch)), image, shown, only, " ({})".format(where) if where else ""
    )


def pinned_refusal(robot, robot_arch, service, platform):
    """The one line that refuses a service pinned to another platform."""
    return "{} is {} but service {} pins platform {}: refused before anything switched".format(
        robot, text(robot_platform(robot_arch)), service, platform
    )


def index_entries(index):
    """The image variants a multi-platform index lists: [{"digest",
    "mediaType", "size", "platform"}], without attestation manifests
    (BuildKit lists them as platform unknown/unknown)."""
    found = []
    for entry in index.get("manifests") or []:
        platform = entry.get("platform") or {}
        annotations = entry.get("annotations") or {}
        if platform.get("os") == "unknown" or "vnd.docker.reference.type" in annotations:
            continue
        found.append(
            {
                "digest": entry.get("digest"),
                "mediaType": entry.get("mediaType"),
                "size": entry.get("size"),
                "platform": platform,
            }
        )
    return found


def choose(entries, robot_arch):
    """The variant of an index a robot of ``robot_arch`` gets, as Docker
    picks it: its architecture, linux; for arm64 the v8 variant (or none)
    before others.  None when the index has none."""
    mine = [e for e in entries if matches(robot_arch, e["platform"])]
    preferred = [e for e in mine if e["platform"].get("variant") in (None, "", "v8")]
    return (preferred or mine or [None])[0]


EXEC_FORMAT = "exec format error"


def exec_format_error(output):
    """Whether a container's output says its program could not be executed
    on this machine at all (the kernel's ENOEXEC)."""
    return EXEC_FORMAT in (output or "").lower()
