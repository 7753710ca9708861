"""The gpu role's settings."""

from __future__ import annotations

from robotfleet import checkers as c
from robotfleet import value_kinds as v
from robotfleet.role import Renamed, Setting

SETTINGS = (
    Setting(
        "gpu_vendor",
        None,
        c.optional(c.string(choices=("nvidia",))),
        "nvidia: this host has an NVIDIA GPU for containers (payload_gpu implies it); the driver must be loaded.",
    ),
    Setting(
        "gpu_repo_url",
        "https://nvidia.github.io/libnvidia-container",
        v.url,
        "NVIDIA's container toolkit repository (or a mirror with its layout): <url>/<channel>/deb/<arch>.",
    ),
    Setting("gpu_apt_channel", "stable", c.string(choices=("stable", "experimental")), "The repository's channel."),
    Setting(
        "gpu_apt_key_url", None, c.optional(v.url), "Where the signing key comes from; null: <gpu_repo_url>/gpgkey."
    ),
    Setting(
        "gpu_apt_key_fingerprint",
        "C95B321B61E88C1809C4F759DDCAE044F796ECB0",
        v.fingerprint,
        "NVIDIA's published key: only this key is installed.",
    ),
    Setting(
        "gpu_apt_key_path",
        "/etc/apt/keyrings/nvidia-container-toolkit.asc",
        v.private_path,
        "Where the key is installed (the source's Signed-By).",
    ),
    Setting(
        "gpu_apt_filename",
        "nvidia-container-toolkit",
        v.file_name,
        "Name of the deb822 source: /etc/apt/sources.list.d/<name>.sources.",
    ),
    Setting(
        "gpu_toolkit_version",
        None,
        c.optional(v.apt_version),
        "Pin nvidia-container-toolkit to one apt version (e.g. 1.17.8-1); null: newest.",
    ),
    Setting("gpu_default_runtime", False, c.boolean, "Make nvidia Docker's default runtime."),
    Setting(
        "gpu_visible_devices",
        "all",
        c.string(
            r"all|none|void|[0-9A-Za-z][0-9A-Za-z:-]*(?:,[0-9A-Za-z][0-9A-Za-z:-]*)*",
            "all, none or GPU indexes/UUIDs separated by commas",
        ),
        "NVIDIA_VISIBLE_DEVICES of the payload.",
    ),
    Setting(
        "gpu_driver_capabilities",
        None,
        c.optional(
            c.string(
                r"all|(?:compute|compat32|graphics|utility|video|display)(?:,(?:compute|compat32|graphics|utility|video|display))*",
                "all or a comma-separated list of compute, compat32, graphics, utility, video, display",
            )
        ),
        "NVIDIA_DRIVER_CAPABILITIES; null: compute,utility (plus graphics where x11_enabled is on).",
    ),
    Setting(
        "gpu_check_command",
        ["nvidia-smi", "-L"],
        c.optional(c.list_of(c.string())),
        "Run in each payload container once healthy; a failure fails the release (rolled back). null: no check.",
    ),
    Setting(
        "gpu_driver_version_file",
        "/proc/driver/nvidia/version",
        v.private_path,
        "Where the loaded driver announces itself (change only to test without a GPU, as the lab does).",
    ),
)
RENAMED = (Renamed("gpu", "gpu_vendor"),)
