"""Where the pull agent lives on a robot, and its configuration file.

Written by the pull role (roles/pull) on a push deploy, or by a first-boot
bundle (``for_host``: a host's pull settings, robotfleet/fleet/pull_mode.py);
read by the agent (robotfleet/pull/robot/agent.py), which checks its numbers
against the same settings' bounds.  Everything is root's: /etc/robot-pull and
/var/lib/robot-pull are 0700.
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import asdict, dataclass, field, replace

from robotfleet.fleet import connection, pull_mode
from robotfleet.pull.protocol import naming
from robotfleet.pull.protocol.host_key_alias import HOST_KEY_ALIAS

ETC = "/etc/robot-pull"
STATE = "/var/lib/robot-pull"
CONFIG = f"{ETC}/agent.json"
TRUST_ROOT = f"{ETC}/root.json"  # the first trust; the agent keeps its own copy from then on
KNOWN_HOSTS = f"{ETC}/known_hosts"  # the git server's host keys
REMOTE_CA = f"{ETC}/remote-ca.pem"  # the CA an https fleet remote's certificate is checked against (if any)
KEY = f"{ETC}/id_ed25519"  # the robot's own key for the fleet remote, made on the robot
VENV = f"{STATE}/venv"  # -> venvs/<id>: the python the agent and pyinfra run in
CODE = f"{STATE}/code"  # <tree sha256>/: deploy trees; current -> the one the agent runs
CURRENT_CODE = f"{CODE}/current"
SERVICE = "robot-pull.service"
TIMER = "robot-pull.timer"
UNIT_DIR = "/etc/systemd/system"
BRANCH = "robotfleet/releases"
FORMAT = 1
# The host data key the agent's converge run sets ({"robot", "version",
# "release"}): the run is the agent's, on the robot itself.
AGENT_RUN = "pull_agent_run"

_ROBOT = re.compile(r"[A-Za-z0-9][A-Za-z0-9._+-]{0,252}\Z")


class ConfigError(ValueError):
    """The agent's configuration cannot be used (one line)."""


# The configuration's whole numbers and the settings that give them, whose
# defaults and bounds they take: pull mode's, and the connection's
# keepalives (the agent's ssh to the fleet remote gives up after their
# silence, its HTTPS after as long).
NUMBERS = {
    "interval": "pull_interval",
    "jitter": "pull_jitter",
    "min_free_mb": "pull_min_free_mb",
    "fetch_timeout": "pull_fetch_timeout",
    "keepalive_interval": "ssh_keepalive_interval",
    "keepalive_count_max": "ssh_keepalive_count_max",
    "stale_after": "pull_stale_after",
    "heartbeat": "pull_heartbeat",
    "report_shards": "pull_report_shards",
}
_SETTINGS = {s.name: s for s in (*pull_mode.SETTINGS, *connection.SETTINGS) if s.name in NUMBERS.values()}
LIMITS = {
    field: (_SETTINGS[name].check.schema["minimum"], _SETTINGS[name].check.schema["maximum"])
    for field, name in NUMBERS.items()
}
_DEFAULT = {field: _SETTINGS[name].default for field, name in NUMBERS.items()}


@dataclass(frozen=True)
class Config:
    robot: str
    remote: str
    interval: int = _DEFAULT["interval"]
    jitter: int = _DEFAULT["jitter"]
    windows: tuple[str, ...] = ()
    min_free_mb: int = _DEFAULT["min_free_mb"]
    fetch_timeout: int = _DEFAULT["fetch_timeout"]
    keepalive_interval: int = _DEFAULT["keepalive_interval"]
    keepalive_count_max: int = _DEFAULT["keepalive_count_max"]
    stale_after: int = _DEFAULT["stale_after"]
    heartbeat: int = _DEFAULT["heartbeat"]
    report_remote: str | None = None  # where reports are pushed; None: remote
    report_shards: int = _DEFAULT["report_shards"]  # (robotfleet/pull/protocol/report_shards.py); 0: one repository
    name_rule: str | None = None  # a shared image's robot derives its name (robotfleet/pull/protocol/naming.py)
    name_prefix: str = ""
    media_dir: str | None = None  # where releases on media are mounted (robotfleet/pull/robot/media.py)
    branch: str = BRANCH
    state_dir: str = STATE
    etc_dir: str = ETC
    docker_dir: str = "/var/lib/docker"
    # What an older agent does not read: it refuses unknown fields, and one a failed release's
    # converge brought back runs with the agent.json that converge wrote.
    extra: dict = field(default_factory=dict)

    @property
    def image_helper(self) -> tuple[str, ...]:
        """A role's argv that puts images in place (robotfleet/role.py Role), kept in ``extra``."""
        return tuple(self.extra.get("image_helper") or ())

    def to_json(self) -> str:
        data = {"format": FORMAT, **asdict(self)}
        data["windows"] = list(self.windows)
        for name, default in (
            ("extra", {}),
            ("report_remote", None),
            ("report_shards", _DEFAULT["report_shards"]),
            ("name_rule", None),
            ("name_prefix", ""),
            ("media_dir", None),
            ("keepalive_interval", _DEFAULT["keepalive_interval"]),
            ("keepalive_count_max", _DEFAULT["keepalive_count_max"]),
        ):
            if data[name] == default:
                del data[name]
        return json.dumps(data, indent=2, sort_keys=True) + "\n"

    def path(self, name: str) -> str:
        """A file of the agent's state directory."""
        return f"{self.state_dir}/{name}"

    def etc(self, name: str) -> str:
        return f"{self.etc_dir}/{name}"


def default(name: str):
    """Config's default for the field ``name``."""
    return Config.__dataclass_fields__[name].default


def for_host(data, robot: str, roles=(), **extra) -> Config:
    """The agent's configuration for a host with ``data`` (its pull settings)
    and the ``roles`` running on it."""
    helper = next((list(r.image_helper) for r in roles if r.image_helper), None)
    return Config(
        robot=robot,
        remote=pull_mode.value(data, "pull_remote"),
        windows=tuple(pull_mode.value(data, "pull_windows")),
        report_remote=pull_mode.value(data, "pull_report_remote"),
        media_dir=pull_mode.value(data, "pull_media_dir"),
        extra={**extra, **({"image_helper": helper} if helper else {})},
        **{field: pull_mode.value(data, name) for field, name in NUMBERS.items()},
    )


def read_config(text: str, where: str = CONFIG) -> Config:
    """The agent's configuration from its JSON; ConfigError naming the field."""
    try:
        raw = json.loads(text)
    except ValueError as error:
        raise ConfigError(f"{where}: not JSON ({error})") from None
    if not isinstance(raw, dict) or raw.get("format") != FORMAT:
        raise ConfigError(f'{where}: expected an object with "format": {FORMAT}')
    known = {f for f in Config.__dataclass_fields__} | {"format"}
    unknown = sorted(set(raw) - known)
    if unknown:
        raise ConfigError(f"{where}: unknown field {unknown[0]!r}")
    if not isinstance(raw.get("remote"), str) or not raw["remote"]:
        raise ConfigError(f"{where}: remote: required, a string")
    if raw.get("name_rule") is not None:
        if raw.get("robot"):
            raise ConfigError(f"{where}: robot and name_rule: give one (a name, or the rule that derives it)")
        try:
            naming.check_rule(raw["name_rule"], raw.get("name_prefix", ""))
        except (naming.NamingError, TypeError) as error:
            raise ConfigError(f"{where}: {error}") from None
        raw = {**raw, "robot": ""}
    elif not isinstance(raw.get("robot"), str) or not raw["robot"]:
        raise ConfigError(f"{where}: robot: required, a string (or name_rule)")
    elif not _ROBOT.match(raw["robot"]):
        raise ConfigError(f"{where}: robot: {raw['robot']!r} is not a robot name")
    for name, (low, high) in LIMITS.items():
        value = raw.get(name, default(name))
        if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
            raise ConfigError(f"{where}: {name}: expected a whole number from {low} to {high}, got {value!r}")
    windows, extra = raw.get("windows", []), raw.get("extra", {})
    if not isinstance(extra, dict):
        raise ConfigError(f"{where}: extra: expected an object")
    helper = extra.get("image_helper", [])
    if not isinstance(windows, list) or not all(isinstance(w, str) for w in windows):
        raise ConfigError(f"{where}: windows: expected a list of maintenance windows")
    if not isinstance(helper, list) or not all(isinstance(a, str) and a for a in helper):
        raise ConfigError(f"{where}: extra.image_helper: expected a command (a list of strings)")
    for name in ("branch", "state_dir", "etc_dir", "docker_dir"):
        if name in raw and (not isinstance(raw[name], str) or not raw[name]):
            raise ConfigError(f"{where}: {name}: expected a string")
    if raw.get("report_remote") is not None and (not isinstance(raw["report_remote"], str) or not raw["report_remote"]):
        raise ConfigError(f"{where}: report_remote: expected a git URL or null")
    for name in ("state_dir", "etc_dir", "docker_dir"):
        if name in raw and not raw[name].startswith("/"):
            raise ConfigError(f"{where}: {name}: expected an absolute path")
    media_dir = raw.get("media_dir")
    if media_dir is not None and (not isinstance(media_dir, str) or not media_dir.startswith("/")):
        raise ConfigError(f"{where}: media_dir: expected an absolute path or null")
    values = {k: v for k, v in raw.items() if k != "format"}
    values["windows"] = tuple(windows)
    return Config(**values)


def named(config: Config, read=None) -> Config:
    """``config`` with its robot's name: given, or derived by its rule from
    this robot's identity (``read(rule)``: the source's text)."""
    if config.name_rule is None:
        return config
    try:
        raw = (read or naming.read)(config.name_rule)
        return replace(config, robot=naming.derive(config.name_rule, config.name_prefix, raw))
    except naming.NamingError as error:
        raise ConfigError(f"robot name: {error}") from None


def known_hosts(data) -> str:
    """The git server's host keys (pull_remote_host_keys) of a host with ``data``, under HOST_KEY_ALIAS."""
    return "".join(f"{HOST_KEY_ALIAS} {key}\n" for key in pull_mode.value(data, "pull_remote_host_keys"))


HEADER = "# Managed by the robot fleet provisioner (roles/pull); local edits are overwritten.\n"
FIRST_BOOT_SERVICE = "robot-pull-first-boot.service"


def start_command(python: str = f"{VENV}/bin/python", config: str = CONFIG) -> list[str]:
    """robot-pull.service's ExecStart, run in the code's directory: the
    entry point every release keeps (robotfleet/pull/agent.py)."""
    return [python, "-m", "robotfleet.pull.agent", "--config", config]


def service_unit() -> str:
    return (
        HEADER
        + f"""[Unit]
Description=Robot fleet pull agent: fetch, verify and apply a signed release (docs/guides/pull.md)
Wants=network-online.target
After=network-online.target {FIRST_BOOT_SERVICE}
ConditionPathExists={CONFIG}

[Service]
Type=oneshot
WorkingDirectory={CURRENT_CODE}
Environment=PYTHONPATH={CURRENT_CODE} PYTHONDONTWRITEBYTECODE=1
ExecStart={VENV}/bin/python -m robotfleet.pull.agent --config {CONFIG}
# A release may install Docker and pull images: hours, not the default 90 s.
TimeoutStartSec=4h
Nice=10
IOSchedulingClass=best-effort
IOSchedulingPriority=7
"""
    )


def timer_unit(data) -> str:
    """robot-pull.timer for a host with ``data``: its pull_interval, pull_jitter and pull_boot_delay."""
    interval, jitter, boot_delay = (
        pull_mode.value(data, f"pull_{name}") for name in ("interval", "jitter", "boot_delay")
    )
    # Persistent= acts only on OnCalendar= timers; a robot that was off
    # catches up through OnBootSec=, the first check after each boot.
    return (
        HEADER
        + f"""[Unit]
Description=Robot fleet pull agent: check for a new release every {interval} s

[Timer]
OnBootSec={boot_delay}
OnActiveSec={boot_delay}
OnUnitInactiveSec={interval}
RandomizedDelaySec={jitter}
Persistent=true
AccuracySec=1s

[Install]
WantedBy=timers.target
"""
    )


def venv_id(wheels) -> str:
    """The identity of a venv made from ``wheels`` [(file name, sha256)]:
    the same set, in any order, is the same venv."""
    digest = hashlib.sha256()
    for name, sha in sorted(wheels):
        digest.update(f"{name} {sha}\n".encode())
    return digest.hexdigest()[:16]
