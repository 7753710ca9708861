"""The engine's pull mode settings, like connection.py's: whether a host
pulls, where it fetches releases, how often, and when it may apply them.
Each is declared here once (name, default, bounds, doc) and read by name
wherever it is needed (``value``): the fleet file's check, the pull role's
steps, the operator's pull commands, and the agent's agent.json
(robotfleet/pull/protocol/agent_files.py takes its defaults and bounds)."""

from __future__ import annotations

import re

from robotfleet import checkers as c
from robotfleet import value_kinds as v
from robotfleet.fleet import connection
from robotfleet.role import Renamed, Setting

# The fleet remote as git takes it (never through a shell, but still no
# character a shell or git's option parser gives a meaning to):
# ssh://user@host[:port]/path, user@host:path, https://host[:port]/path.
_HOST = rf"(?:{v.DNS_NAME}|{v.IPV4}|\[[0-9A-Fa-f:.]+\])"
_PATH = r"[A-Za-z0-9._~/+-]*[A-Za-z0-9._~+-]"
REMOTE = (
    rf"ssh://[a-z_][a-z0-9_.-]*@{_HOST}(?::[0-9]{{1,5}})?/{_PATH}"
    rf"|[a-z_][a-z0-9_.-]*@{_HOST}:{_PATH}"
    rf"|https://{_HOST}(?::[0-9]{{1,5}})?/{_PATH}"
)
REMOTE_WHAT = "a git URL: ssh://user@host[:port]/path, user@host:path or https://host/path"
HOST_KEY = r"(?:ssh-ed25519|ssh-rsa|ecdsa-sha2-nistp(?:256|384|521)) [A-Za-z0-9+/]+={0,3}"
HOST_KEY_WHAT = "a public host key like 'ssh-ed25519 AAAA...' (ssh-keyscan's line without the host)"


def _any_case(word: str) -> str:
    return "".join(f"[{ch.upper()}{ch}]" if ch.isalpha() else ch for ch in word)


_DAY = (
    "(?:"
    + "|".join(
        _any_case(short) + f"(?:{_any_case(rest)})?"
        for short, rest in (
            ("mon", "day"),
            ("tue", "sday"),
            ("wed", "nesday"),
            ("thu", "rsday"),
            ("fri", "day"),
            ("sat", "urday"),
            ("sun", "day"),
        )
    )
    + ")"
)
_TIME = "(?:[01]?[0-9]|2[0-3]):[0-5][0-9]"
# What robotfleet/pull/protocol/waves.py reads, in ASCII and single spaces (a JSON
# Schema pattern too); a window that starts when it ends is the run's alone.
WINDOW = (
    rf"(?:{_any_case('daily')}|\*|{_DAY}(?:-{_DAY})?(?:,{_DAY}(?:-{_DAY})?)*) +{_TIME}-{_TIME}"
    rf"(?: +(?:{_any_case('utc')}|{_any_case('local')}))?"
)
_WINDOW_CHECK = c.string(WINDOW, "a maintenance window like 'Mon-Fri 01:00-05:00' or 'daily 22:00-02:00 UTC'")


def window(value):
    """A maintenance window: DAYS HH:MM-HH:MM [UTC], as robotfleet/pull/protocol/waves.py reads it."""
    problems = _WINDOW_CHECK(value)
    times = [] if problems else [[int(n) for n in time.split(":")] for time in re.findall(r"[0-9]+:[0-9]+", value)]
    if times and times[0] == times[1]:
        return [("", f"maintenance window {value!r}: starts and ends at the same time; for all day write 00:00-23:59")]
    return problems


c.with_schema(window, _WINDOW_CHECK.schema)

# A pull robot runs pyinfra 3 and this tree (pyproject.toml's requires-python): Python 3.10 or later.
MIN_PYTHON = (3, 10)
WAY_OUT = "provision it by push (pull_enabled: false), or give it a python3 of 3.10 or later"


def too_old(version: str) -> str | None:
    """Why a pull robot whose python is ``version`` ('3.8', '38') cannot pull, naming the way out
    (the end of one line: "this robot's " + it); None when it can."""
    major, minor = (version.split(".", 1) if "." in version else (version[:1], version[1:])) if version else ("", "")
    if not (major.isdigit() and minor.isdigit()) or (int(major), int(minor)) >= MIN_PYTHON:
        return None
    return (
        f"python3 {major}.{minor} is too old for pull mode (the robot runs pyinfra 3, which needs "
        f"Python {MIN_PYTHON[0]}.{MIN_PYTHON[1]} or later): {WAY_OUT}"
    )


SETTINGS = (
    Setting(
        "pull_enabled",
        False,
        c.boolean,
        "This host converges itself from the signed releases robotfleet publish writes (docs/guides/pull.md).",
    ),
    Setting(
        "pull_platform",
        "cp313-x86_64",
        c.string(r"cp3[0-9]{1,2}-(x86_64|aarch64|armv7l)", "a platform like cp313-x86_64 (Python, machine)"),
        "A pull host's Python and machine (cp313-x86_64, cp311-aarch64): the wheels its releases carry.",
    ),
    Setting(
        "pull_remote",
        None,
        c.optional(c.string(REMOTE, REMOTE_WHAT)),
        "The fleet remote the agent fetches releases from and pushes its reports to (required with pull_enabled).",
    ),
    Setting(
        "pull_report_remote",
        None,
        c.optional(c.string(REMOTE, REMOTE_WHAT)),
        "Where the agent pushes its reports, when not to pull_remote (e.g. ssh to the git server while releases "
        "come from an https mirror); null: pull_remote.",
    ),
    Setting(
        "pull_report_shards",
        0,
        c.integer(0, 4096),
        "Report repositories beside the fleet remote (<remote>-reports-<n>), each robot's fixed by a hash of its "
        "name; about one per 16 robots keeps a report push under 10 KB, with the server's read copy of them "
        "(files/git-server/post-receive) for the readers; 0: the reports in the fleet remote itself. "
        "The same on every robot.",
    ),
    Setting(
        "pull_remote_ca",
        None,
        c.optional(v.local_path),
        "PEM file of the CA an https pull_remote's certificate is checked against (relative to the checkout; "
        "keep it in the deploy tree, e.g. files/); null: the robot's system CAs.",
    ),
    Setting(
        "pull_remote_host_keys",
        [],
        c.list_of(c.string(HOST_KEY, HOST_KEY_WHAT), unique=True),
        "The git server's SSH host keys, checked strictly by the agent (required for an ssh remote).",
    ),
    Setting(
        "pull_interval",
        900,
        c.integer(10, 7 * 86400),
        "Seconds between two checks for a new release (the timer's OnUnitInactiveSec).",
    ),
    Setting(
        "pull_jitter",
        300,
        c.integer(0, 86400),
        "Up to this many seconds added at random to each wait, so robots do not wake at once (RandomizedDelaySec).",
    ),
    Setting(
        "pull_boot_delay",
        60,
        c.integer(0, 86400),
        "Seconds after boot (or after the agent is installed) before the first check (OnBootSec).",
    ),
    Setting(
        "pull_windows",
        [],
        c.list_of(window, unique=True),
        "Maintenance windows a release may start in (Mon-Fri 01:00-05:00, daily 22:00-02:00 UTC); none: any time.",
    ),
    Setting(
        "pull_min_free_mb",
        512,
        c.integer(0, 1 << 20),
        "Free MB the agent needs on its state directory's and Docker's file systems before it downloads.",
    ),
    Setting(
        "pull_heartbeat",
        3600,
        c.integer(10, 7 * 86400),
        "Seconds after which a robot with nothing new reads its roles' status again and pushes its report anyway.",
    ),
    Setting(
        "pull_stale_after",
        2,
        c.integer(1, 1000),
        "status marks a pull robot's report stale when it is older than this many heartbeats (each plus an "
        "interval and its jitter).",
    ),
    Setting("pull_fetch_timeout", 300, c.integer(5, 86400), "Seconds one fetch from the fleet remote may take."),
    Setting(
        "pull_media_dir",
        None,
        c.optional(v.private_path),
        "Where releases on removable media or a LAN share are mounted (robotfleet export; e.g. /mnt/fleet-media): "
        "looked at each check, the newer signed release of it and the fleet remote is taken; null: never.",
    ),
    Setting(
        "pull_trust_root",
        None,
        c.optional(v.local_path),
        "The release repository's root.json on this machine, the robot's first trust (relative to the checkout); "
        "null: the one robotfleet publish keeps (.robotfleet/releases/metadata/root.json).",
    ),
)

RENAMED = (Renamed("pull", "pull_enabled"),)

# The pull settings, and the connection settings the agent reuses (its keepalives).
_DEFAULTS = {setting.name: setting.default for setting in (*SETTINGS, *connection.SETTINGS)}


def value(data, name: str):
    """The pull or connection setting ``name`` of a host's data (pyinfra's,
    the fleet file's, or a mapping): its declared default where the data has none."""
    found = data.get(name) if hasattr(data, "get") else getattr(data, name, None)
    return _DEFAULTS[name] if found is None else found


def pulls(data) -> bool:
    """Whether a host with ``data`` converges itself from signed releases."""
    return value(data, "pull_enabled") is True


def rules(data: dict, refused: frozenset) -> list[c.Problem]:
    if data.get("pull_enabled") is not True or "pull_enabled" in refused:
        return []
    problems = []
    remote = data.get("pull_remote")
    if remote is None and "pull_remote" not in refused:
        problems.append(
            (
                "pull_remote",
                "required when pull_enabled is true: the git URL of the fleet remote "
                "(e.g. ssh://gitolite3@git.example.com/fleet)",
            )
        )
    elif (
        any(isinstance(url, str) and not url.startswith("https://") for url in (remote, data.get("pull_report_remote")))
        and not data.get("pull_remote_host_keys")
        and "pull_remote_host_keys" not in refused
    ):
        problems.append(
            (
                "pull_remote_host_keys",
                "required for an ssh remote: the git server's host keys "
                "(ssh-keyscan HOST, checked against the server's own)",
            )
        )
    platform = data.get("pull_platform")
    old = too_old(str(platform)[2:].split("-")[0]) if "pull_platform" not in refused else None
    if old:
        problems.append(("pull_platform", f"{platform}: a robot's {old}"))
    return problems
