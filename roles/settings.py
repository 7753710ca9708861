"""What each fleet setting may hold.  Defaults live in group_data/ (one place);
this module only knows types and rules, so it can check data before any host
is contacted.
"""

from __future__ import annotations

import difflib
import ipaddress
import posixpath
import re

from roles import checks as c
from roles import imageref

SUBSYSTEMS = ("tty", "video4linux", "hidraw", "input", "usb", "sound")
DEFAULT_SENSOR_GROUP = {
    "tty": "dialout",
    "video4linux": "video",
    "sound": "audio",
    "input": "input",
}
SENSOR_KEYS = (
    "name",
    "subsystem",
    "serial",
    "vendor_id",
    "product_id",
    "usb_port",
    "group",
    "mode",
    "symlink",
    "passthrough",
    "services",  # roles/payload/services.py: the compose services that get the device
)
USB_PORT = r"[0-9]+-[0-9]+(?:\.[0-9]+)*(?::[0-9]+\.[0-9]+)?"
# udev match values are quoted strings: keep them to characters that need no
# escaping, so a value can never end the rule or inject a key.
UDEV_VALUE = r"[A-Za-z0-9._:/+ -]{1,126}"
MODE = r"0?[0-7]{3}"
SYMLINK = r"[A-Za-z0-9_][A-Za-z0-9_.-]*(?:/[A-Za-z0-9_][A-Za-z0-9_.-]*)*"


# URLs reach root shells and apt sources on every robot: http(s) only, and no
# character a shell or an apt line gives a meaning to (no $ ` ; | & quotes,
# spaces, backslashes, parentheses, < >).
URL = r"https?://(?:[A-Za-z0-9._~-]+|\[[0-9A-Fa-f:.]+\])(?::[0-9]{1,5})?(?:/[A-Za-z0-9._~%/+,=@:-]*)?(?:\?[A-Za-z0-9._~%/+,=@:-]*)?"
URL_WHAT = "an http(s) URL without spaces or shell characters ($ ` ; | & quotes)"
# Directories anyone may write to: a path at or below one can be planted or
# swapped by a local user before root creates, chmods or reads it.
WORLD_WRITABLE = ("/tmp", "/var/tmp", "/dev/shm", "/run/lock", "/var/lock", "/dev/mqueue")
_DOTTED_NUMBERS = re.compile(r"[0-9.]+")
_HOST_PORT = re.compile(r"([^:\s\[\]]+|\[[^\]]*\]):([0-9]+)")
_DNS_NAME = re.compile(r"(?=.{1,253}\.?$)[A-Za-z0-9_](?:[A-Za-z0-9_-]{0,61}[A-Za-z0-9_])?(?:\.[A-Za-z0-9_](?:[A-Za-z0-9_-]{0,61}[A-Za-z0-9_])?)*\.?", re.ASCII)


def _address(value):
    """A host name, an IPv4 or an IPv6 address (what SSH connects to)."""
    if not isinstance(value, str):
        return [("", c.expected_string(value, "a host name or an IP address"))]
    try:
        ipaddress.ip_address(value)
        return []
    except ValueError:
        pass
    if value.startswith("[") and value.endswith("]"):
        return [("", f"expected an IPv6 address without brackets, got {c.shown(value)}")]
    host_port = _HOST_PORT.fullmatch(value)
    if host_port:
        return [("", f"expected a host name or an IP address, got {c.shown(value)}; put the port in ssh_port: {host_port.group(2)}")]
    if _DOTTED_NUMBERS.fullmatch(value):
        return [("", f"{c.shown(value)} is not a valid IPv4 address")]
    if not _DNS_NAME.fullmatch(value) or value.rstrip(".").rsplit(".", 1)[-1].isdigit():
        return [("", f"expected a host name or an IP address, got {c.shown(value)}")]
    return []


_url = c.string(URL, URL_WHAT)
def _local_path(value):
    """A file on the operator's machine (never sent to a host): any path
    that prints as itself (no control or direction-changing characters)."""
    if not isinstance(value, str):
        return [("", c.expected_string(value, "a path on this machine"))]
    if not value or not value.isprintable():
        return [("", f"expected a path on this machine of printable characters, got {c.shown(value)}")]
    return []


def _image(value):
    problems = c.string()(value)
    if problems:
        return problems
    try:
        imageref.parse(value)
    except ValueError as error:
        return [("", str(error))]
    return []


def _volume(value):
    problems = c.string()(value)
    if problems:
        return problems
    parts = value.split(":")
    if len(parts) not in (2, 3) or not all(p.startswith("/") for p in parts[:2]):
        return [("", f"expected 'host_path:container_path[:ro]' with absolute paths, got {c.shown(value)}")]
    if len(parts) == 3 and parts[2] not in ("ro", "rw"):
        return [("", f"mount option must be ro or rw, got {c.shown(parts[2])}")]
    if any(".." in p.split("/") for p in parts[:2]):
        return [("", f"paths must not contain '..', got {c.shown(value)}")]
    if not all(re.fullmatch(c.ABS_PATH, p, re.ASCII) for p in parts[:2]):
        return [("", f"paths may hold letters, digits and . _ / @ + - only, got {c.shown(value)}")]
    return []


def _abs_path(value):
    problems = c.string(c.ABS_PATH, "an absolute path")(value)
    if not problems and ".." in value.split("/"):
        return [("", f"paths must not contain '..', got {c.shown(value)}")]
    return problems


def _private_path(value):
    """A path root creates, chmods or writes: not in a world-writable directory."""
    problems = _abs_path(value)
    if problems:
        return problems
    normal = "/" + posixpath.normpath(value).lstrip("/")
    for shared in WORLD_WRITABLE:
        if normal == shared or normal.startswith(shared + "/"):
            return [("", f"{c.shown(value)} is in the world-writable {shared}; use a directory only root can write (e.g. under /var/lib)")]
    return []


def _udev_rules_path(value):
    problems = _abs_path(value)
    if not problems and not (value.startswith("/etc/udev/rules.d/") and value.endswith(".rules")):
        return [("", f"expected a file in /etc/udev/rules.d/ ending in .rules, got {c.shown(value)}")]
    return problems


_vendor_rule_name = c.string(r"[A-Za-z0-9_.-]+\.rules", "a file name in files/udev/ ending in .rules")


_FINGERPRINT = c.string(r"[0-9A-Fa-f]{40}", "a 40-digit hex OpenPGP fingerprint")


def _fingerprint(value):
    return _FINGERPRINT(value.replace(" ", "") if isinstance(value, str) else value)


_SENSOR_FIELDS = {
    "name": c.string(c.IDENTIFIER, "a name of lowercase letters, digits, - and _"),
    "subsystem": c.string(choices=SUBSYSTEMS),
    "serial": c.string(UDEV_VALUE, "a serial of letters, digits and . _ : / + -"),
    "vendor_id": c.string(c.HEX4, "a 4-digit hex USB vendor id"),
    "product_id": c.string(c.HEX4, "a 4-digit hex USB product id"),
    "usb_port": c.string(USB_PORT, "a USB port path like 1-2.1"),
    "group": c.string(c.USER_NAME, "a group name"),
    "mode": c.string(MODE, "an octal mode like \"0660\""),
    "symlink": c.string(SYMLINK, "a path relative to /dev like robot/front_camera"),
    "passthrough": c.boolean,
    "services": c.list_of(c.string(r"[a-zA-Z0-9][a-zA-Z0-9._-]*", "a service name"), unique=True),
}


def _sensor(value):
    if not isinstance(value, dict):
        return [("", f"expected a mapping with at least name and subsystem, got {c.describe(value)}")]
    problems = []
    for key in value:
        if not isinstance(key, str):
            problems.append((f".{c.key_name(key)}", f"a sensor field name must be a string, got {c.describe(key)}; quote it"))
        elif key not in SENSOR_KEYS:
            problems.append((f".{c.key_name(key)}", "unknown sensor field" + did_you_mean(key, SENSOR_KEYS)))
    for key in ("name", "subsystem"):
        if key not in value:
            problems.append((f".{key}", "required"))
    for key, check in _SENSOR_FIELDS.items():
        if key in value:
            problems += [(f".{key}{sub}", msg) for sub, msg in check(value[key])]
    if ("vendor_id" in value) != ("product_id" in value):
        missing = "product_id" if "vendor_id" in value else "vendor_id"
        problems.append((f".{missing}", "vendor_id and product_id go together"))
    if not any(k in value for k in ("serial", "vendor_id", "usb_port")):
        problems.append(("", "needs a match: serial, vendor_id/product_id or usb_port"))
    return problems


def _services():
    from roles.payload import services  # late: roles.payload imports this module

    return services


# daemon.json keys and value kinds from Docker's dockerd reference ("Daemon
# configuration file", Linux).  b: boolean, s: string, i: whole number,
# l: list of strings, m: mapping, ms: mapping of strings, j: any JSON (checked by dockerd --validate).
DAEMON_OPTIONS = {
    **dict.fromkeys(
        "debug experimental live-restore icc init ip-forward ip-masq iptables ip6tables ipv6 "
        "no-new-privileges raw-logs selinux-enabled tls tlsverify userland-proxy "
        "ip-forward-no-drop allow-direct-routing bridge-accept-fwmark".split(), "b"),
    **dict.fromkeys(
        "api-cors-header bip bip6 bridge cgroup-parent containerd containerd-namespace "
        "containerd-plugins-namespace cpu-rt-period cpu-rt-runtime data-root default-cgroupns-mode "
        "default-gateway default-gateway-v6 default-ipc-mode default-runtime default-shm-size exec-root "
        "fixed-cidr fixed-cidr-v6 group host-gateway-ip init-path ip log-driver log-format log-level "
        "pidfile seccomp-profile storage-driver swarm-default-advertise-addr tlscacert tlscert tlskey "
        "userland-proxy-path userns-remap firewall-backend".split(), "s"),
    **dict.fromkeys(
        "max-concurrent-downloads max-concurrent-uploads max-download-attempts mtu oom-score-adjust "
        "shutdown-timeout network-control-plane-mtu".split(), "i"),
    **dict.fromkeys(
        "allow-nondistributable-artifacts authorization-plugins cdi-spec-dirs dns dns-opts dns-search "
        "exec-opts hosts insecure-registries labels node-generic-resources registry-mirrors "
        "storage-opts host-gateway-ips".split(), "l"),
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


def _daemon_options(value):
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
            problems.append((where, "unknown daemon.json option" + did_you_mean(key, DAEMON_OPTIONS)))
        else:
            problems += [(f"{where}{sub}", msg) for sub, msg in _DAEMON_KIND[DAEMON_OPTIONS[key]](option)]
    return problems


# What the checkers above accept, as JSON Schema for editors (roles/schema.py).
_path_schema = {"type": "string", "pattern": c.json_pattern(c.ABS_PATH), "description": "an absolute path without '..'"}
c.with_schema(_address, {"type": "string", "description": "a host name, an IPv4 or an IPv6 address (the port goes in ssh_port)"})
c.with_schema(_image, {"type": "string", "description": "an image reference, pinned by tag or digest"})
c.with_schema(_volume, {"type": "string", "pattern": "^/[^:]*:/[^:]*(?::(?:ro|rw))?$", "description": "host_path:container_path[:ro]"})
c.with_schema(_abs_path, _path_schema)
c.with_schema(_local_path, {"type": "string", "description": "a path on this machine"})
c.with_schema(_private_path, {
    **_path_schema,
    "not": {"pattern": "^/+(?:" + "|".join(w.lstrip("/") for w in WORLD_WRITABLE) + ")(?:/|$)"},
    "description": "an absolute path outside world-writable directories (/tmp, /var/tmp, /dev/shm, ...)",
})
c.with_schema(_udev_rules_path, {"type": "string", "pattern": "^/etc/udev/rules\\.d/[A-Za-z0-9._@+-]+\\.rules$"})
c.with_schema(_fingerprint, {"type": "string", "pattern": "^(?: *[0-9A-Fa-f]){40} *$", "description": "a 40-digit hex OpenPGP fingerprint"})
c.with_schema(_sensor, {
    "type": "object",
    "properties": {key: check.schema for key, check in _SENSOR_FIELDS.items()},
    "required": ["name", "subsystem"],
    "anyOf": [{"required": [key]} for key in ("serial", "vendor_id", "usb_port")],
    "additionalProperties": False,
})
c.with_schema(_daemon_options, {
    "type": "object",
    "properties": {key: _DAEMON_KIND[kind].schema for key, kind in DAEMON_OPTIONS.items()},
    "additionalProperties": False,
    "description": "/etc/docker/daemon.json",
})

SCHEMA: dict[str, c.Checker] = {
    # SSH / connection
    "ssh_hostname": _address,
    "ssh_user": c.string(c.USER_NAME, "a user name"),
    "ssh_port": c.integer(1, 65535),
    "ssh_key": _local_path,
    "ssh_known_hosts_file": _local_path,
    "ssh_strict_host_key_checking": c.string(choices=("yes", "accept-new", "no")),
    "ssh_connect_retries": c.integer(0, 100),
    "ssh_connect_retry_min_delay": c.integer(0, 600),
    "ssh_connect_retry_max_delay": c.integer(0, 600),
    # apt
    "apt_lock_timeout": c.integer(0, 86400),
    # Docker engine
    "docker_source": c.string(choices=("docker", "distro")),
    "docker_repo_url": _url,
    "docker_apt_release_channel": c.string(choices=("stable", "test")),
    "docker_apt_key_url": c.optional(_url),
    "docker_apt_key_fingerprint": c.optional(_fingerprint),
    "docker_apt_key_sha256": c.optional(c.string(r"[0-9a-f]{64}", "a 64-digit lowercase hex sha256")),
    "docker_apt_key_path": _private_path,
    "docker_apt_filename": c.string(r"[A-Za-z0-9][A-Za-z0-9_.-]*", "a file name"),
    "docker_apt_legacy_files": c.list_of(_private_path),
    "docker_packages": c.list_of(c.string(r"[a-z0-9][a-z0-9.+-]+", "a package name"), unique=True),
    "docker_version": c.optional(c.string(r"[0-9][0-9A-Za-z.+~:-]*", "an apt version string")),
    "docker_distro_packages": c.optional(c.list_of(c.string(r"[a-z0-9][a-z0-9.+-]+", "a package name"))),
    "docker_obsolete_packages": c.list_of(c.string(r"[a-z0-9][a-z0-9.+-]+", "a package name")),
    "docker_daemon_options": _daemon_options,
    "docker_registry_mirrors": c.list_of(_url),
    "docker_insecure_registries": c.list_of(c.string(r"[A-Za-z0-9][A-Za-z0-9.-]*(?::[0-9]+)?(?:/[0-9]+)?", "host[:port]")),
    "docker_restart_handler_state": c.string(choices=("restarted", "reloaded")),
    "docker_restart_timeout": c.integer(5, 3600),
    "docker_service_enabled": c.boolean,
    "docker_users": c.list_of(c.string(c.USER_NAME, "a user name"), unique=True),
    # udev
    "sensors": c.list_of(_sensor),
    "udev_rules_file": _udev_rules_path,
    "udev_vendor_rules": c.list_of(_vendor_rule_name, unique=True),
    "udev_allow_world_writable": c.boolean,
    # X11
    "display": c.boolean,
    "x11_user": c.optional(c.string(c.USER_NAME, "a user name")),
    "x11_display": c.string(r"(?:[A-Za-z0-9.-]*):[0-9]+(?:\.[0-9]+)?", "an X display like :0"),
    "x11_cookie_dir": _private_path,
    # payload
    "payload_image": c.optional(_image),
    "payload_allow_latest": c.boolean,
    "payload_name": c.string(c.IDENTIFIER, "a name of lowercase letters, digits, - and _"),
    "payload_dir": _private_path,
    "payload_delivery": c.string(choices=("pull", "push")),
    "payload_autostart": c.boolean,
    "payload_restart_policy": c.string(choices=("no", "always", "on-failure", "unless-stopped")),
    "payload_network_mode": c.string(choices=("host", "bridge", "none")),
    "payload_environment": c.mapping_of(c.string(c.ENV_NAME, "an environment variable name"), c.text),
    "payload_command": c.optional(c.list_of(c.string())),
    "payload_volumes": c.list_of(_volume),
    "payload_gpu": c.boolean,
    "ros_domain_id": c.integer(0, 232),
    "ros_master_uri": c.optional(c.string(r"https?://[A-Za-z0-9.-]+(?::[0-9]+)?/?", "a URL like http://master:11311")),
    "ros_hostname": c.optional(_address),
    "payload_health_timeout": c.integer(5, 3600),
    "payload_stable_seconds": c.integer(0, 600),
    "payload_pull_timeout": c.integer(5, 86400),
    "payload_apply_lock_timeout": c.integer(0, 86400),
    "payload_device_wait": c.integer(0, 600),
    "payload_keep_releases": c.integer(2, 50),
    "payload_lock_file": _private_path,
    "payload_force": c.boolean,
    "payload_registry_username_env": c.string(c.ENV_NAME, "an environment variable name"),
    "payload_registry_password_env": c.string(c.ENV_NAME, "an environment variable name"),
    # --- the payload as a compose project (roles/payload/services.py) ---
    "payload_services": c.with_schema(
        lambda value: _services().layer_problems(value),
        {
            "type": "object",
            "description": "service name -> a Compose service (checked against the Compose Specification "
            "before connecting); null removes a service set by a group",
            "additionalProperties": {"type": ["object", "null"]},
        },
    ),
    "payload_replaces": c.list_of(c.string(r"[a-zA-Z0-9][a-zA-Z0-9_.-]*", "a container or compose project name"), unique=True),
    "payload_allow_privileged": c.boolean,
    "ros_preset": c.optional(c.string(choices=("ros1", "ros2"))),
    "ros_roscore": c.boolean,
    "ros_roscore_image": c.optional(_image),
    "ros_dds_profile": c.optional(c.string(r"[A-Za-z0-9_.-]+\.xml", "a file name in files/dds/ ending in .xml")),
}


# NVIDIA GPUs (roles/gpu): a separate block so it merges cleanly.
SCHEMA.update({
    "gpu": c.optional(c.string(choices=("nvidia",))),
    "gpu_repo_url": _url,
    "gpu_apt_channel": c.string(choices=("stable", "experimental")),
    "gpu_apt_key_url": c.optional(_url),
    "gpu_apt_key_fingerprint": _fingerprint,
    "gpu_apt_key_path": _private_path,
    "gpu_apt_filename": c.string(r"[A-Za-z0-9][A-Za-z0-9_.-]*", "a file name"),
    "gpu_toolkit_version": c.optional(c.string(r"[0-9][0-9A-Za-z.+~:-]*", "an apt version string")),
    "gpu_default_runtime": c.boolean,
    "gpu_visible_devices": c.string(
        r"all|none|void|[0-9A-Za-z][0-9A-Za-z:-]*(?:,[0-9A-Za-z][0-9A-Za-z:-]*)*",
        "all, none or GPU indexes/UUIDs separated by commas",
    ),
    "gpu_driver_capabilities": c.optional(c.string(
        r"all|(?:compute|compat32|graphics|utility|video|display)(?:,(?:compute|compat32|graphics|utility|video|display))*",
        "all or a comma-separated list of compute, compat32, graphics, utility, video, display")),
    "gpu_check_command": c.optional(c.list_of(c.string())),
    "gpu_driver_version_file": _private_path,
})
# Rollouts in waves (roles/rollout.py): kept apart from the roles' settings.
SCHEMA["rollout_canary"] = c.boolean


# Keys the fleet file may use that are not settings of their own.
ALIASES = {"address": "ssh_hostname"}


# Settings whose documented values include yes/no: YAML 1.1 reads an unquoted
# yes/no as a boolean, so those booleans mean the documented word.
YES_NO = {
    "ssh_strict_host_key_checking": {True: "yes", False: "no"},
    "payload_restart_policy": {False: "no"},
}


def normalize(layer: dict) -> dict:
    """``layer`` with unquoted yes/no read back as the documented words."""
    if not any(key in layer for key in YES_NO):
        return layer
    fixed = dict(layer)
    for key, words in YES_NO.items():
        value = fixed.get(key)
        if isinstance(value, bool) and value in words:
            fixed[key] = words[value]
    return fixed


def did_you_mean(key: str, known) -> str:
    close = difflib.get_close_matches(key, list(known), n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def check_layer(data: dict) -> list[c.Problem]:
    """Problems in one layer of data (a host, a group's vars): keys and types."""
    problems = []
    for key, value in data.items():
        if not isinstance(key, str):
            problems.append((c.key_name(key), f"a setting name must be a string, got {c.describe(key)}; quote it"))
            continue
        name = ALIASES.get(key, key)
        if name not in SCHEMA:
            known = list(SCHEMA) + list(ALIASES)
            problems.append((c.key_name(key), "unknown setting" + did_you_mean(key, known)))
            continue
        problems += [(f"{key}{sub}", msg) for sub, msg in SCHEMA[name](value)]
    return problems


def setting_of(field: str) -> str:
    """The setting a problem's field belongs to: sensors[1].serial -> sensors."""
    return field.split(".")[0].split("[")[0]


def check_host(data: dict, refused=frozenset()) -> list[c.Problem]:
    """Rules that need a host's merged data (defaults + every layer).  A
    setting in ``refused`` already has a problem: no rule looks at it again."""
    usable = {k: v for k, v in data.items() if k not in refused} if refused else data
    problems = []
    if "payload_image" not in refused and "payload_services" not in refused:
        image = usable.get("payload_image")
        if image is not None and not usable.get("payload_services") and "payload_allow_latest" not in refused:
            why = imageref.pinning_problem(image, usable.get("payload_allow_latest", False))
            if why:
                problems.append(("payload_image", why))
        problems += _services().host_problems(usable)  # the compose project (roles/payload/services.py)
    if usable.get("display") is True and "x11_user" not in refused and not usable.get("x11_user"):
        problems.append(("x11_user", "required when display is true: the desktop user"))
    if usable.get("ros_master_uri") and usable.get("ros_domain_id"):
        problems.append(("ros_master_uri", "set either ros_master_uri (ROS 1) or ros_domain_id (ROS 2), not both"))
    sensors = data.get("sensors")
    if isinstance(sensors, list) and "udev_allow_world_writable" not in refused:
        # A refused list still has sensors that are valid on their own.
        valid = [(i, s) for i, s in enumerate(sensors) if "sensors" not in refused or not _sensor(s)]
        problems += _sensor_set_problems(valid, usable.get("udev_allow_world_writable") is True)
    return problems


def _sensor_set_problems(sensors: list[tuple[int, dict]], allow_world_writable: bool) -> list[c.Problem]:
    """Rules across sensors, over (index, sensor) pairs of sensors that are
    valid on their own."""
    problems = []
    names, links, matches = {}, {}, {}
    for index, sensor in sensors:
        where = f"sensors[{index}]"
        name = sensor["name"]
        if name in names:
            problems.append((f"{where}.name", f"duplicate sensor name {name!r} (also sensors[{names[name]}])"))
        names.setdefault(name, index)
        link = sensor.get("symlink") or f"robot/{name}"
        if link in links:
            problems.append((f"{where}.symlink", f"/dev/{link} is already used by sensors[{links[link]}]"))
        links.setdefault(link, index)
        match = tuple(sensor.get(k) for k in ("subsystem", "serial", "vendor_id", "product_id", "usb_port"))
        if match in matches:
            problems.append(
                (where, f"matches the same devices as sensors[{matches[match]}]; add a serial or usb_port to tell them apart")
            )
        matches.setdefault(match, index)
        mode = sensor.get("mode")
        if mode is not None and int(mode, 8) & 0o002 and not allow_world_writable:
            problems.append((f"{where}.mode", f"{mode} is world-writable; use a group (or set udev_allow_world_writable)"))
    return problems


def data_problems(data) -> list[str]:
    """Problems in a host's final data (pyinfra host.data, including --data
    overrides, which never went through the fleet file), as 'field: message'."""
    missing = object()
    values = {}
    for key in SCHEMA:
        value = data.get(key, missing)
        if value is not missing:
            values[key] = value
    layer = check_layer(values)
    problems = layer + check_host(values, {setting_of(field) for field, _ in layer})
    return [f"{field}: {message}" for field, message in problems]
