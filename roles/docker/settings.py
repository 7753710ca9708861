"""The docker role's settings: default, check, one line of documentation."""

from __future__ import annotations

from dataclasses import dataclass

from robotfleet import checkers as c
from robotfleet import value_kinds as v
from robotfleet.role import Renamed, Setting


@dataclass(frozen=True)
class DaemonSetting(Setting):
    """A setting written into daemon.json under ``key``, over
    docker_daemon_options: a list is merged into that option's list, any
    other value (but null) replaces it.  Declaring one is all it takes."""

    key: str = ""


def daemon_keys(data) -> dict:
    """daemon.json key -> the host's value, for each DaemonSetting."""
    return {s.key: data.get(s.name) for s in SETTINGS if isinstance(s, DaemonSetting)}


# daemon.json keys and value kinds from Docker's dockerd reference ("Daemon
# configuration file", Linux).  b: boolean, s: string, i: whole number,
# l: list of strings, m: mapping, ms: mapping of strings, j: any JSON (checked by dockerd --validate).
DAEMON_OPTIONS = {
    **dict.fromkeys(
        "debug experimental live-restore icc init ip-forward ip-masq iptables ip6tables ipv6 "
        "no-new-privileges raw-logs selinux-enabled tls tlsverify userland-proxy "
        "ip-forward-no-drop allow-direct-routing bridge-accept-fwmark".split(),
        "b",
    ),
    **dict.fromkeys(
        "api-cors-header bip bip6 bridge cgroup-parent containerd containerd-namespace "
        "containerd-plugins-namespace cpu-rt-period cpu-rt-runtime data-root default-cgroupns-mode "
        "default-gateway default-gateway-v6 default-ipc-mode default-runtime default-shm-size exec-root "
        "fixed-cidr fixed-cidr-v6 group host-gateway-ip init-path ip log-driver log-format log-level "
        "pidfile seccomp-profile storage-driver swarm-default-advertise-addr tlscacert tlscert tlskey "
        "userland-proxy-path userns-remap firewall-backend".split(),
        "s",
    ),
    **dict.fromkeys(
        "max-concurrent-downloads max-concurrent-uploads max-download-attempts mtu oom-score-adjust "
        "shutdown-timeout network-control-plane-mtu".split(),
        "i",
    ),
    **dict.fromkeys(
        "allow-nondistributable-artifacts authorization-plugins cdi-spec-dirs dns dns-opts dns-search "
        "exec-opts hosts insecure-registries labels node-generic-resources registry-mirrors "
        "storage-opts host-gateway-ips".split(),
        "l",
    ),
    **dict.fromkeys("builder default-network-opts default-ulimits features runtimes".split(), "m"),
    **dict.fromkeys("log-opts proxies".split(), "ms"),
    **dict.fromkeys("default-address-pools".split(), "j"),
}
_DAEMON_KIND = {
    "b": c.boolean,
    "s": c.string(),
    "i": c.integer(),
    "l": c.list_of(c.string()),
    "m": c.mapping_of(c.string(), c.any_json),
    "ms": c.mapping_of(c.string(), c.string()),
    "j": c.any_json,
}


def daemon_options(value):
    if not isinstance(value, dict):
        return [("", f"expected a mapping of daemon.json options, got {c.describe(value)}")]
    too_big = c.size_problem(value)
    if too_big:
        return too_big
    problems = []
    for key, option in value.items():
        where = f".{c.key_name(key)}"
        if not isinstance(key, str):
            problems.append((where, f"expected a daemon.json option name, got {c.describe(key)}; quote it"))
        elif key not in DAEMON_OPTIONS:
            problems.append((where, "unknown daemon.json option" + c.did_you_mean(key, DAEMON_OPTIONS)))
        else:
            problems += [(f"{where}{sub}", msg) for sub, msg in _DAEMON_KIND[DAEMON_OPTIONS[key]](option)]
    return problems


c.with_schema(
    daemon_options,
    {
        "type": "object",
        "properties": {key: _DAEMON_KIND[kind].schema for key, kind in DAEMON_OPTIONS.items()},
        "additionalProperties": False,
        "description": "/etc/docker/daemon.json",
    },
)

LEGACY_FILES = [
    "/etc/apt/sources.list.d/docker.list",
    "/etc/apt/sources.list.d/download_docker_com_linux_ubuntu.list",
    "/etc/apt/sources.list.d/download_docker_com_linux_debian.list",
    "/etc/apt/sources.list.d/docker-ce.list",
    "/etc/apt/sources.list.d/docker-ce-stable.list",
    "/etc/apt/trusted.gpg.d/docker.asc",
    "/etc/apt/trusted.gpg.d/docker.gpg",
    "/etc/apt/keyrings/docker.gpg",
]

SETTINGS = (
    Setting(
        "docker_source",
        "docker",
        c.string(choices=("docker", "distro")),
        "docker: Docker CE from Docker's apt repository; distro: the distribution's docker.io + compose v2.",
    ),
    Setting(
        "docker_repo_url",
        "https://download.docker.com/linux",
        v.url,
        "Base URL of Docker's repository (or a local mirror); the distribution (ubuntu, debian) is appended.",
    ),
    Setting(
        "docker_apt_release_channel",
        "stable",
        c.string(choices=("stable", "test")),
        "The repository's channel (apt component).",
    ),
    Setting(
        "docker_apt_key_url",
        None,
        c.optional(v.url),
        "Where the repository's signing key comes from; null: <docker_repo_url>/<distribution>/gpg.",
    ),
    Setting(
        "docker_apt_key_fingerprint",
        "9DC858229FC7DD38854AE2D88D81803C0EBFCD88",
        c.optional(v.fingerprint),
        "The key's OpenPGP fingerprint (Docker's published one): only this key is installed; null: no check.",
    ),
    Setting(
        "docker_apt_key_sha256",
        None,
        c.optional(c.string(r"[0-9a-f]{64}", "a 64-digit lowercase hex sha256")),
        "Optional sha256 of the downloaded key file.",
    ),
    Setting(
        "docker_apt_key_path",
        "/etc/apt/keyrings/docker.asc",
        v.private_path,
        "Where the key is installed (the source's Signed-By).",
    ),
    Setting(
        "docker_apt_filename",
        "docker",
        v.file_name,
        "Name of the deb822 source: /etc/apt/sources.list.d/<name>.sources.",
    ),
    Setting(
        "docker_apt_legacy_files",
        LEGACY_FILES,
        c.list_of(v.private_path),
        "Source and key files of older install methods, removed (apt refuses conflicting Signed-By).",
    ),
    Setting(
        "docker_packages",
        ["docker-ce", "docker-ce-cli", "containerd.io", "docker-buildx-plugin", "docker-compose-plugin"],
        c.list_of(v.package_name, unique=True),
        "Packages installed from Docker's repository.",
    ),
    Setting(
        "docker_version",
        None,
        c.optional(v.apt_version),
        "Pin docker-ce and docker-ce-cli to one apt version (e.g. 5:28.5.2-1~ubuntu.24.04~noble); null: newest.",
    ),
    Setting(
        "docker_distro_packages",
        None,
        c.optional(c.list_of(v.package_name)),
        "Packages for docker_source: distro; null: docker.io + the distribution's compose v2 package.",
    ),
    Setting(
        "docker_obsolete_packages",
        ["docker.io", "docker-doc", "docker-compose", "docker-compose-v2", "podman-docker", "containerd", "runc"],
        c.list_of(v.package_name),
        "Removed before installing Docker CE, where installed and while Docker CE is not ([] keeps them).",
    ),
    Setting(
        "docker_daemon_options",
        {"live-restore": True, "log-driver": "json-file", "log-opts": {"max-size": "10m", "max-file": "3"}},
        daemon_options,
        "/etc/docker/daemon.json (rotated logs; live-restore keeps containers across restarts).",
    ),
    DaemonSetting(
        "docker_registry_mirrors",
        [],
        c.list_of(v.url),
        "Merged into daemon.json's registry-mirrors.",
        key="registry-mirrors",
    ),
    DaemonSetting(
        "docker_insecure_registries",
        [],
        c.list_of(c.string(r"[A-Za-z0-9][A-Za-z0-9.-]*(?::[0-9]+)?(?:/[0-9]+)?", "host[:port]")),
        "Merged into daemon.json's insecure-registries.",
        key="insecure-registries",
    ),
    Setting(
        "docker_allow_unauthenticated_tcp",
        False,
        c.boolean,
        "Allow daemon.json hosts to open a TCP listener without TLS client verification "
        "(anyone who reaches it is root).",
    ),
    Setting(
        "docker_daemon_config_change",
        "restart",
        c.string(choices=("restart", "reload")),
        "What a daemon.json change does to the engine.",
    ),
    Setting(
        "docker_restart_timeout",
        60,
        c.integer(5, 3600),
        "Seconds Docker has to be active again after a daemon.json change, or the previous file comes back.",
    ),
    Setting("docker_service_enabled", True, c.boolean, "Start Docker at boot."),
    Setting(
        "docker_users",
        [],
        c.list_of(v.user_name, unique=True),
        "Existing users added to the docker group (root-equivalent); users are never created.",
    ),
)
RENAMED = (
    Renamed(
        "docker_restart_handler_state",
        "docker_daemon_config_change",
        values={"restarted": "restart", "reloaded": "reload"},
    ),
)


# What dockerd needs to accept only clients holding a certificate its CA signed.
TLS_VERIFY = ("tlsverify", "tlscacert", "tlscert", "tlskey")


def tcp_listener(value) -> bool:
    """A daemon.json ``hosts`` entry dockerd opens on the network: anything
    but a unix socket or systemd's fd:// (dockerd reads "0.0.0.0:2375" and
    "tcp://" alone as TCP too)."""
    return isinstance(value, str) and not value.startswith(("unix://", "fd://"))


def rules(data: dict, refused: frozenset) -> list[c.Problem]:
    """The Docker API on TCP without client certificates is root on the host
    for anyone who reaches the port (localhost: any local user): refused
    unless TLS verification is set or the operator opts in by name."""
    options = data.get("docker_daemon_options")
    if "docker_daemon_options" in refused or not isinstance(options, dict):
        return []
    listeners = [(i, h) for i, h in enumerate(options.get("hosts") or []) if tcp_listener(h)]
    if not listeners or data.get("docker_allow_unauthenticated_tcp") is True:  # a refused value allows nothing
        return []
    missing = [key for key in TLS_VERIFY if options.get(key) in (None, False, "")]
    if not missing:
        return []
    index, listener = listeners[0]
    return [
        (
            f"docker_daemon_options.hosts[{index}]",
            f"{c.shown(listener)} opens the Docker API on TCP without TLS client verification (missing: "
            f"{', '.join(missing)}): anyone who reaches it is root on this host; set tlsverify: true, "
            "tlscacert, tlscert and tlskey, or docker_allow_unauthenticated_tcp: true",
        )
    ]
