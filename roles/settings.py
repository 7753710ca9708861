"""What each fleet setting may hold.  Defaults live in group_data/ (one place);
this module only knows types and rules, so it can check data before any host
is contacted.
"""

from __future__ import annotations

import difflib
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
)
USB_PORT = r"[0-9]+-[0-9]+(?:\.[0-9]+)*(?::[0-9]+\.[0-9]+)?"
# udev match values are quoted strings: keep them to characters that need no
# escaping, so a value can never end the rule or inject a key.
UDEV_VALUE = r"[A-Za-z0-9._:/+ -]{1,126}"
MODE = r"0?[0-7]{3}"
SYMLINK = r"[A-Za-z0-9_][A-Za-z0-9_.-]*(?:/[A-Za-z0-9_][A-Za-z0-9_.-]*)*"


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
        return [("", f"expected 'host_path:container_path[:ro]' with absolute paths, got {value!r}")]
    if len(parts) == 3 and parts[2] not in ("ro", "rw"):
        return [("", f"mount option must be ro or rw, got {parts[2]!r}")]
    if any(".." in p.split("/") for p in parts[:2]):
        return [("", f"paths must not contain '..', got {value!r}")]
    return []


def _abs_path(value):
    problems = c.string(c.ABS_PATH, "an absolute path")(value)
    if not problems and ".." in value.split("/"):
        return [("", f"paths must not contain '..', got {value!r}")]
    return problems


def _udev_rules_path(value):
    problems = _abs_path(value)
    if not problems and not (value.startswith("/etc/udev/rules.d/") and value.endswith(".rules")):
        return [("", f"expected a file in /etc/udev/rules.d/ ending in .rules, got {value!r}")]
    return problems


def _vendor_rule_name(value):
    return c.string(r"[A-Za-z0-9_.-]+\.rules", "a file name in files/udev/ ending in .rules")(value)


def _fingerprint(value):
    if isinstance(value, str):
        value = value.replace(" ", "")
    return c.string(r"[0-9A-Fa-f]{40}", "a 40-digit hex OpenPGP fingerprint")(value)


def _sensor(value):
    if not isinstance(value, dict):
        return [("", f"expected a mapping with at least name and subsystem, got {c.describe(value)}")]
    problems = []
    for key in value:
        if key not in SENSOR_KEYS:
            problems.append((f".{key}", "unknown sensor field" + did_you_mean(key, SENSOR_KEYS)))
    for key in ("name", "subsystem"):
        if key not in value:
            problems.append((f".{key}", "required"))
    field_checks = {
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
    }
    for key, check in field_checks.items():
        if key in value:
            problems += [(f".{key}{sub}", msg) for sub, msg in check(value[key])]
    if ("vendor_id" in value) != ("product_id" in value):
        missing = "product_id" if "vendor_id" in value else "vendor_id"
        problems.append((f".{missing}", "vendor_id and product_id go together"))
    if not any(k in value for k in ("serial", "vendor_id", "usb_port")):
        problems.append(("", "needs a match: serial, vendor_id/product_id or usb_port"))
    return problems


SCHEMA: dict[str, c.Checker] = {
    # SSH / connection
    "ssh_hostname": c.string(r"[A-Za-z0-9.:_-]+", "a host name or address"),
    "ssh_user": c.string(c.USER_NAME, "a user name"),
    "ssh_port": c.integer(1, 65535),
    "ssh_key": c.string(what="a path to a private key file"),
    "ssh_known_hosts_file": c.string(what="a path to a known_hosts file"),
    "ssh_strict_host_key_checking": c.string(choices=("yes", "accept-new", "no")),
    "ssh_connect_retries": c.integer(0, 100),
    "ssh_connect_retry_min_delay": c.integer(0, 600),
    "ssh_connect_retry_max_delay": c.integer(0, 600),
    # Docker engine
    "docker_source": c.string(choices=("docker", "distro")),
    "docker_repo_url": c.string(r"https?://[^\s\"']+", "an http(s) URL"),
    "docker_apt_release_channel": c.string(choices=("stable", "test")),
    "docker_apt_key_url": c.optional(c.string(r"https?://[^\s\"']+", "an http(s) URL")),
    "docker_apt_key_fingerprint": c.optional(_fingerprint),
    "docker_apt_key_sha256": c.optional(c.string(r"[0-9a-f]{64}", "a 64-digit lowercase hex sha256")),
    "docker_apt_key_path": _abs_path,
    "docker_apt_filename": c.string(r"[A-Za-z0-9_.-]+", "a file name"),
    "docker_apt_legacy_files": c.list_of(_abs_path),
    "docker_packages": c.list_of(c.string(r"[a-z0-9][a-z0-9.+-]+", "a package name"), unique=True),
    "docker_version": c.optional(c.string(r"[0-9A-Za-z.+~:-]+", "an apt version string")),
    "docker_distro_packages": c.optional(c.list_of(c.string(r"[a-z0-9][a-z0-9.+-]+", "a package name"))),
    "docker_obsolete_packages": c.list_of(c.string(r"[a-z0-9][a-z0-9.+-]+", "a package name")),
    "docker_daemon_options": c.mapping_of(c.string(), c.any_json),
    "docker_registry_mirrors": c.list_of(c.string(r"https?://[^\s\"']+", "an http(s) URL")),
    "docker_insecure_registries": c.list_of(c.string(r"[A-Za-z0-9.-]+(?::[0-9]+)?(?:/[0-9]+)?", "host[:port]")),
    "docker_restart_handler_state": c.string(choices=("restarted", "reloaded")),
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
    "x11_cookie_dir": _abs_path,
    # payload
    "payload_image": c.optional(_image),
    "payload_allow_latest": c.boolean,
    "payload_name": c.string(c.IDENTIFIER, "a name of lowercase letters, digits, - and _"),
    "payload_dir": _abs_path,
    "payload_delivery": c.string(choices=("pull", "push")),
    "payload_autostart": c.boolean,
    "payload_restart_policy": c.string(choices=("no", "always", "on-failure", "unless-stopped")),
    "payload_network_mode": c.string(choices=("host", "bridge", "none")),
    "payload_environment": c.mapping_of(c.string(c.ENV_NAME, "an environment variable name"), c.scalar),
    "payload_command": c.optional(c.list_of(c.string())),
    "payload_volumes": c.list_of(_volume),
    "payload_gpu": c.boolean,
    "ros_domain_id": c.integer(0, 232),
    "ros_master_uri": c.optional(c.string(r"https?://[A-Za-z0-9.-]+(?::[0-9]+)?/?", "a URL like http://master:11311")),
    "ros_hostname": c.optional(c.string(r"[A-Za-z0-9.-]+", "a host name")),
    "payload_health_timeout": c.integer(5, 3600),
    "payload_stable_seconds": c.integer(0, 600),
    "payload_pull_timeout": c.integer(5, 86400),
    "payload_apply_lock_timeout": c.integer(0, 86400),
    "payload_device_wait": c.integer(0, 600),
    "payload_keep_releases": c.integer(2, 50),
    "payload_lock_file": _abs_path,
    "payload_force": c.boolean,
    "payload_registry_username_env": c.string(c.ENV_NAME, "an environment variable name"),
    "payload_registry_password_env": c.string(c.ENV_NAME, "an environment variable name"),
}

# Keys the fleet file may use that are not settings of their own.
ALIASES = {"address": "ssh_hostname"}


def did_you_mean(key: str, known) -> str:
    close = difflib.get_close_matches(key, list(known), n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def check_layer(data: dict) -> list[c.Problem]:
    """Problems in one layer of data (a host, a group's vars): keys and types."""
    problems = []
    for key, value in data.items():
        name = ALIASES.get(key, key)
        if name not in SCHEMA:
            known = list(SCHEMA) + list(ALIASES)
            problems.append((key, "unknown setting" + did_you_mean(key, known)))
            continue
        problems += [(f"{key}{sub}", msg) for sub, msg in SCHEMA[name](value)]
    return problems


def check_host(data: dict) -> list[c.Problem]:
    """Rules that need a host's merged data (defaults + every layer)."""
    problems = []
    image = data.get("payload_image")
    if image is None:
        problems.append(("payload_image", "required: the payload image, pinned by tag or digest"))
    else:
        why = imageref.pinning_problem(image, data.get("payload_allow_latest", False))
        if why:
            problems.append(("payload_image", why))
    if data.get("display") and not data.get("x11_user"):
        problems.append(("x11_user", "required when display is true: the desktop user"))
    if data.get("ros_master_uri") and data.get("ros_domain_id"):
        problems.append(("ros_master_uri", "set either ros_master_uri (ROS 1) or ros_domain_id (ROS 2), not both"))
    sensors = data.get("sensors") or []
    if isinstance(sensors, list):
        problems += _sensor_set_problems(sensors, data.get("udev_allow_world_writable", False))
    return problems


def _sensor_set_problems(sensors: list, allow_world_writable: bool) -> list[c.Problem]:
    problems = []
    names, links, matches = {}, {}, {}
    for index, sensor in enumerate(sensors):
        if not isinstance(sensor, dict):
            continue
        where = f"sensors[{index}]"
        name = sensor.get("name")
        if name in names:
            problems.append((f"{where}.name", f"duplicate sensor name {name!r} (also sensors[{names[name]}])"))
        names.setdefault(name, index)
        link = sensor.get("symlink") or f"robot/{name}"
        if link in links and name is not None:
            problems.append((f"{where}.symlink", f"/dev/{link} is already used by sensors[{links[link]}]"))
        links.setdefault(link, index)
        match = tuple(sensor.get(k) for k in ("subsystem", "serial", "vendor_id", "product_id", "usb_port"))
        if match in matches:
            problems.append(
                (where, f"matches the same devices as sensors[{matches[match]}]; add a serial or usb_port to tell them apart")
            )
        matches.setdefault(match, index)
        mode = sensor.get("mode")
        if isinstance(mode, str) and re.fullmatch(MODE, mode) and int(mode, 8) & 0o002 and not allow_world_writable:
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
    problems = check_layer(values) + check_host(values)
    return [f"{field}: {message}" for field, message in problems]
