"""The payload role's settings: the image or compose services, ROS
networking, the release's bounds and the registry credentials' names."""

from __future__ import annotations

import re

import roles.payload.credentials as credentials
import roles.payload.digests as digests
import roles.payload.payloadctl.imageref as imageref
import roles.payload.payloadctl.platforms as platforms
import roles.payload.presets as presets
import roles.payload.problems as problems
import roles.payload.ros_health as ros_health
import roles.payload.secret_files as secret_files
import roles.payload.services as services
from robotfleet import checkers as c
from robotfleet import value_kinds as v
from robotfleet.role import Renamed, Setting


def parsed_by(parse):
    """A check: a string that ``parse`` accepts (its ValueError is the problem)."""

    def check(value):
        found = c.string()(value)
        if found:
            return found
        try:
            parse(value)
        except ValueError as error:
            return [("", str(error))]
        return []

    return check


image = parsed_by(imageref.parse)


def volume(value):
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


_NAME = r"[a-zA-Z0-9][a-zA-Z0-9_.-]*"


def replaced(value):
    """container:NAME or project:NAME: a container name and a compose project
    name look alike, and taking over the wrong one stops someone else's."""
    problems = c.string()(value)
    if problems:
        return problems
    kind, sep, name = value.partition(":")
    if not sep and re.fullmatch(_NAME, value):
        return [
            (
                "",
                f"{c.shown(value)} could be a container or a compose project: "
                f"write container:{value} or project:{value}",
            )
        ]
    if kind not in ("container", "project") or not re.fullmatch(_NAME, name):
        return [("", f"expected container:NAME or project:NAME, got {c.shown(value)}")]
    return []


platform = parsed_by(platforms.parse)


c.with_schema(
    platform,
    {
        "type": "string",
        "pattern": "^[a-z0-9]+/[a-z0-9_]+(?:/[a-z0-9]+)?$",
        "description": "os/architecture[/variant], e.g. linux/arm64",
    },
)
c.with_schema(
    replaced,
    {"type": "string", "pattern": f"^(?:container|project):{_NAME}$", "description": "container:NAME or project:NAME"},
)
c.with_schema(
    image,
    {"type": "string", "pattern": imageref.JSON_PATTERN, "description": "an image reference, pinned by tag or digest"},
)
c.with_schema(
    volume,
    {"type": "string", "pattern": "^/[^:]*:/[^:]*(?::(?:ro|rw))?$", "description": "host_path:container_path[:ro]"},
)
payload_services = c.with_schema(
    services.layer_problems,
    {
        "type": "object",
        "description": "service name -> a Compose service (checked against the Compose Specification "
        "before connecting); null removes a service set by a group",
        "additionalProperties": {"type": ["object", "null"]},
    },
)
_env_name = c.string(c.ENV_NAME, "an environment variable name")


def lock_token(value):
    """A token `payloadctl hold` made (64 hex digits); a wrong one is
    refused without being shown."""
    if isinstance(value, str) and re.fullmatch(r"[0-9a-f]{32,128}", value):
        return []
    return [("", "expected the token payloadctl hold wrote (hex digits); the value is not shown")]


c.with_schema(
    lock_token,
    {
        "type": "string",
        "pattern": "^[0-9a-f]{32,128}$",
        "description": "a token payloadctl hold wrote (set by the pull agent, never by hand)",
    },
)

digest = c.string(digests.DIGEST, "a digest: sha256: and 64 lowercase hex digits")
_pins = c.mapping_of(image, digest)


def image_pins(value):
    """A mapping image -> digest (pyinfra's --data turns JSON text into one;
    text that is not valid JSON arrives as a string)."""
    if isinstance(value, str):
        return [
            (
                "",
                f"expected a mapping image -> digest, got {c.shown(value)}; on --data give JSON text: "
                'payload_image_pins=\'{"reg/ros/payload:1.1": "sha256:..."}\'',
            )
        ]
    return _pins(value)


c.with_schema(image_pins, _pins.schema)

SETTINGS = (
    Setting("payload_image", None, c.optional(image), "The ROS payload image, pinned by tag or digest."),
    Setting("payload_allow_latest", False, c.boolean, "Allow the moving tag 'latest'."),
    Setting(
        "payload_name",
        "robot-payload",
        c.string(c.IDENTIFIER, "a name of lowercase letters, digits, - and _"),
        "Compose project, systemd unit (<name>.service) and directory name.",
    ),
    Setting("payload_dir", "/var/lib/robot-payload", v.private_path, "Where the releases live on the host."),
    Setting(
        "payload_delivery",
        "pull",
        c.string(choices=("pull", "push")),
        "pull: the robot pulls from the registry; push: sent from this machine's Docker engine over SSH.",
    ),
    Setting(
        "payload_autostart",
        True,
        c.boolean,
        "Start the payload at boot (robots) or only stage it (laptops).",
        groups={"robots": True, "laptops": False},
    ),
    Setting(
        "payload_restart_policy",
        "unless-stopped",
        c.string(choices=("no", "always", "on-failure", "unless-stopped")),
        "The containers' restart policy.",
    ),
    Setting("payload_network_mode", "host", c.string(choices=("host", "bridge", "none")), "The containers' network."),
    Setting(
        "payload_stop_grace_period",
        None,
        c.optional(c.integer(0, 3600)),
        "Seconds a container has to stop on its signal before it is killed (compose stop_grace_period); "
        "null: Docker's 10.",
    ),
    Setting(
        "payload_init",
        False,
        c.boolean,
        "Run an init process as PID 1 (compose init): it passes signals on to an entrypoint that is a shell.",
    ),
    Setting(
        "payload_environment",
        {},
        c.mapping_of(_env_name, c.text),
        "Extra container environment; values reach the container verbatim.",
    ),
    Setting("payload_command", None, c.optional(c.list_of(c.string())), "The container's command; null: the image's."),
    Setting("payload_volumes", [], c.list_of(volume), "Extra bind mounts, host_path:container_path[:ro]."),
    Setting("payload_gpu", False, c.boolean, "Give the payload the host's NVIDIA GPUs (the gpu role runs)."),
    Setting(
        "payload_platform",
        None,
        c.optional(platform),
        "The image's platform (linux/arm64) where a vendor ships one tag per architecture; null: the robot's own.",
    ),
    Setting("ros_domain_id", 0, c.integer(0, 232), "ROS 2 ROS_DOMAIN_ID."),
    Setting(
        "ros_master_uri",
        None,
        c.optional(c.string(r"https?://[A-Za-z0-9.-]+(?::[0-9]+)?/?", "a URL like http://master:11311")),
        "ROS 1 ROS_MASTER_URI (instead of ros_domain_id).",
    ),
    Setting("ros_hostname", None, c.optional(v.address), "ROS 1 ROS_HOSTNAME; null: the host's address."),
    Setting("payload_health_timeout", 120, c.integer(5, 3600), "Seconds for a new release to become healthy."),
    Setting(
        "payload_stable_seconds",
        10,
        c.integer(0, 600),
        "For images without a HEALTHCHECK: seconds it must run without restarting.",
    ),
    Setting("payload_pull_timeout", 300, c.integer(5, 86400), "Seconds for docker pull, all tries."),
    Setting(
        "payload_apply_lock_timeout",
        300,
        c.integer(0, 86400),
        "Seconds to wait for another deploy, rollback or boot recovery of the same robot.",
    ),
    Setting("payload_device_wait", 30, c.integer(0, 600), "Seconds to wait at boot for the sensors' device links."),
    Setting(
        "payload_keep_releases",
        3,
        c.integer(2, 50),
        "Releases kept on the robot (their images too, for offline rollback).",
    ),
    Setting(
        "payload_update_lock_path",
        "/run/robot-payload/update.lock",
        v.private_path,
        "The update lock: while this file exists on the robot, updates are refused unless forced.",
    ),
    Setting("payload_force", False, c.boolean, "Update although the update lock is held."),
    Setting(
        "payload_lock_token",
        None,
        c.optional(lock_token),
        "The apply lock's token of the run this deploy is part of (payloadctl hold); never printed.",
    ),
    Setting(
        "payload_switch_request",
        None,
        c.optional(v.private_path),
        "Set by the pull agent's planning run on the robot (@local, --dry): a release is written here for its "
        "window's switch instead of applied; ignored anywhere else.",
    ),
    Setting(
        digests.SETTING,
        {},
        image_pins,
        "Image -> the digest it runs by; normally set by the pull agent from a signed release, not by hand.",
    ),
    Setting(
        "payload_registry_username_env",
        "PAYLOAD_REGISTRY_USERNAME",
        _env_name,
        "Environment variable (on this machine) holding the registry user; never stored, never printed.",
    ),
    Setting(
        "payload_registry_password_env",
        "PAYLOAD_REGISTRY_PASSWORD",
        _env_name,
        "Environment variable (on this machine) holding the registry password or token.",
    ),
    Setting(
        "payload_registry_auths",
        {},
        credentials.auths,
        "Credentials per registry (as Docker's auths): registry -> username_env/username_file, "
        "password_env/password_file (files outside the checkout), token_realms; each goes to its registry only.",
    ),
    Setting(
        secret_files.SETTING,
        {},
        secret_files.check,
        "Secrets the containers read: name -> a file on this machine (outside the checkout), sent to the robot "
        "0600 and mounted at /run/secrets/NAME; never in the fleet file or a release.",
    ),
    Setting(
        "payload_services",
        {},
        payload_services,
        "Several services instead of payload_image: name -> a Compose service; layers merge per service and key.",
        merge=services.merge_values,
    ),
    Setting(
        "payload_replaces",
        [],
        c.list_of(replaced, unique=True),
        "What was set up another way and the payload replaces: container:NAME or project:NAME (a compose project).",
    ),
    Setting("payload_allow_privileged", False, c.boolean, "Allow privileged services."),
    Setting(
        "ros_preset",
        None,
        c.optional(c.string(choices=("ros1", "ros2"))),
        "ros1 or ros2: the usual ROS environment, ipc and DDS profile in one line.",
    ),
    Setting("ros_roscore", False, c.boolean, "ROS 1: run roscore as a service of the project."),
    Setting("ros_roscore_image", None, c.optional(image), "ROS 1: the roscore image, pinned."),
    Setting(
        "ros_log_dir",
        "/var/log/ros",
        v.private_path,
        "ROS presets: the host directory every node logs to (ROS_LOG_DIR), kept across releases and rollbacks.",
    ),
    Setting(
        ros_health.SETTING,
        None,
        ros_health.check,
        "ROS 1 with ros_roscore: what a healthy release publishes (nodes, topics: {/chatter: 2 Hz}, services).",
    ),
    Setting("ros_log_max_mb", 500, c.integer(10), "ROS presets: the logs' size; the oldest files go, every 10 min."),
    Setting("ros_bag_dir", None, c.optional(v.private_path), "ROS presets: host directory at /bags in every service."),
    Setting("ros_bag_max_mb", 2000, c.integer(10), "ROS presets: ros_bag_dir's size; the oldest .bag files go first."),
    Setting(
        "ros_dds_profile",
        None,
        c.optional(c.string(r"[A-Za-z0-9_.-]+\.xml", "a file name in files/dds/ ending in .xml")),
        "ROS 2: a DDS profile from files/dds/ (Cyclone DDS or Fast DDS XML), mounted read-only.",
    ),
)
RENAMED = (Renamed("payload_lock_file", "payload_update_lock_path"),)

DEFAULTS = {setting.name: setting.default for setting in SETTINGS}


def rules(data: dict, refused: frozenset) -> list[c.Problem]:
    """The project as a whole: the image pinned, the services checked
    against the Compose Specification, ROS 1 or ROS 2 but not both."""
    # Only the payload's own settings (and the DDS profile's file) count, and
    # the hosts of a group mostly share them: each distinct set is built and
    # checked once (5,000 robots build one compose project, not 5,000).
    own = {k: data[k] for k in DEFAULTS if k in data and k not in refused}
    try:
        key = (_frozen(own), frozenset(DEFAULTS.keys() & refused), presets.dds_profile_text(own))
    except TypeError:  # a value of a type the key cannot tell apart: no memo
        return _rules(own, refused)
    return list(_memo(key, own, refused))


def _frozen(value):
    """``value`` as a hashable key that tells every value apart, types and
    order included (True from 1, [1] from (1,), Misread("010") from 10)."""
    if value is None or type(value) in (str, int, float, bool):
        return type(value), value
    if isinstance(value, dict):
        return dict, tuple((_frozen(k), _frozen(v)) for k, v in value.items())
    if isinstance(value, (list, tuple)):
        return type(value), tuple(_frozen(v) for v in value)
    if isinstance(value, c.Misread):
        return c.Misread, _frozen(value.value), value.text
    raise TypeError(type(value).__name__)


_MEMO: dict = {}


def _memo(key, own: dict, refused: frozenset) -> tuple:
    if key not in _MEMO:
        if len(_MEMO) >= 256:
            _MEMO.clear()
        _MEMO[key] = tuple(_rules(own, refused))
    return _MEMO[key]


def _rules(usable: dict, refused: frozenset) -> list[c.Problem]:
    found = []
    if "payload_image" not in refused and "payload_services" not in refused:
        single = usable.get("payload_image")
        if single is not None and not usable.get("payload_services"):
            # a refused payload_allow_latest is not in usable: it allows nothing
            why = imageref.pinning_problem(single, usable.get("payload_allow_latest", False))
            if why:
                found.append(("payload_image", why))
        found += problems.host_problems(usable, DEFAULTS)
    if not refused & {"payload_image", "payload_services", "payload_delivery", digests.SETTING}:
        found += digests.problems(usable)
    if "payload_registry_auths" not in refused:
        found += credentials.files_in_checkout(usable.get("payload_registry_auths"))
    if not refused & {secret_files.SETTING, "payload_services"}:
        found += secret_files.problems(usable)
    found += ros_health.problems(usable)
    if usable.get("ros_master_uri") and usable.get("ros_domain_id"):
        found.append(("ros_master_uri", "set either ros_master_uri (ROS 1) or ros_domain_id (ROS 2), not both"))
    return found
