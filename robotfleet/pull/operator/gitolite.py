"""The fleet remote on gitolite (Debian's gitolite3): who may read and write what.

The remote the robots use is one repository holding the releases branch
(``robotfleet/releases``) and the robots' reports (``refs/reports/<robot>``).
gitolite decides reads per repository, writes per ref: every robot may read
the repository, and may write only its own report ref, one rule per robot
with its name escaped.  (gitolite's ``USER`` in a refex would be one rule for
all, but gitolite 3.6 replaces it only between slashes, ``refs/reports/USER/``,
and unescaped: robot ``r.1`` could then write the report of ``rx1``.)  Keep
the deploy repository (its history, other branches) out of this one: a
robot can read all of it.

A robot's gitolite user is its name: ``<robot>.pub`` is its own key,
``<robot>@enroll.pub`` the single-use enrollment key of a first-boot
bundle (gitolite reads ``name@anything.pub`` as user ``name``); the operator
removes the second once the robot's own key is registered.  Both live in
the fleet's own key directory, ``keydir/robotfleet/<repo>/``, and the rules
in the fleet's own conf file: on a server that serves a team's other
repositories nothing else of the admin repository is touched
(robotfleet/pull/operator/gitolite_admin.py).  ``key_file()`` names a key
as ``keydir/<file>``; ``update()`` puts it in the fleet's directory.

A bundle for an image shared by many robots (``robotfleet bundle
--name-from``) carries one enrollment key for all of them, gitolite user
``enroll+<rule>+<prefix>``: it may read, and write the report ref of any
name the rule can derive with that prefix (``refs/reports/robot-[0-9a-f]{12}$``)
except those of robots already registered (a deny rule each, first), so a
leaked image cannot speak for an enrolled robot.

With the reports sharded (``pull_report_shards``: n report repositories
``<repo>-reports-<i>``, robotfleet/pull/protocol/report_shards.py), each
shard is a repository every robot may read, and a robot writes its report
ref only in its own shard (the shared enrollment user: its names in every
shard, a registered robot's denied in that robot's shard).  The fleet
repository keeps each robot's rule for its own report ref meanwhile, so a
robot that has not moved yet (its configuration from before the shard
count) still reports there.

The operator changes the server by pushing its admin repository
(``gitolite-admin``), so ``register`` works against any gitolite the operator
administers, over SSH with strict host keys.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

from robotfleet import keepalive
from robotfleet.pull.operator import gitolite_admin
from robotfleet.pull.protocol import report_shards

REPORTS = "refs/reports"
ENROLL_SUFFIX = "@enroll"
SHARED = "enroll+"  # a shared image's enrollment user: enroll+<rule>+<prefix>
# gitolite user names (and so robot names in pull mode): what gitolite's own
# USERNAME_PATT accepts, without '@' (ours marks a second key of a user).
ROBOT_NAME = re.compile(r"[A-Za-z0-9][-0-9a-zA-Z._+]*\Z")
KEY_LINE = re.compile(r"(ssh-ed25519|ssh-rsa|ecdsa-sha2-nistp(256|384|521)) [A-Za-z0-9+/=]+( .*)?\Z")
GIT_TIMEOUT = 60
IDENTITY = ("-c", "user.name=robotfleet", "-c", "user.email=robotfleet@localhost")
# What one push may bring (git's receive.maxInputSize), each repository's
# through gitolite's rules: a push larger is cut off as it arrives.  The
# fleet repository takes the operator's releases (code and wheels); a shard
# only reports, each at most 256 KiB (files/git-server/pre-receive refuses
# any other shape of report, in both).
MAX_INPUT = {"fleet": "1g", "shard": "1m"}


class GitoliteError(Exception):
    """One line: what failed on the gitolite server, and why."""


def check_robot(name: str) -> str:
    if not isinstance(name, str) or not ROBOT_NAME.match(name):
        raise GitoliteError(f"{name!r} cannot be a gitolite user (letters, digits, '-', '.', '_', '+')")
    return name


def check_key(text: str, what: str) -> str:
    """One OpenSSH public key line, without its comment."""
    lines = [line.strip() for line in text.strip().splitlines() if line.strip()]
    if len(lines) != 1 or not KEY_LINE.match(lines[0]):
        raise GitoliteError(f"{what}: not one OpenSSH public key line")
    return " ".join(lines[0].split()[:2])


def shared_user(rule: str, prefix: str) -> str:
    from robotfleet.pull.protocol import naming

    naming.check_rule(rule, prefix)
    return f"{SHARED}{rule}+{prefix}"


def shared_refex(user: str) -> str:
    """The robot names a shared enrollment user may report as (a regex)."""
    from robotfleet.pull.protocol import naming

    _, rule, prefix = user.split("+", 2)
    return re.escape(prefix) + naming.PATTERNS[rule]


def conf(repo: str, robots, admins=("admin",), shards: int = report_shards.SINGLE) -> str:
    """The fleet's own conf file (conf/robotfleet/<repo>.conf, which
    gitolite.conf includes: robotfleet/pull/operator/gitolite_admin.py): the
    fleet repository every robot reads and writes only its own report ref of
    (a shared image's enrollment user: any report ref its rule can name but a
    registered robot's); with ``shards``, a block per report shard likewise,
    each robot's rule in its own shard only."""
    admin = " ".join(admins)
    team = gitolite_admin.group(repo)
    lines = [gitolite_admin.HEADER.format(repo=repo), ""]
    users = sorted({check_robot(r) for r in robots})
    shared = [u for u in users if u.startswith(SHARED)]
    robots = [u for u in users if not u.startswith(SHARED)]
    if users:
        lines += [f"{team} = {' '.join(users)}", ""]
    lines += _block(repo, admin, team, users, robots, shared, MAX_INPUT["fleet"])
    by_shard = report_shards.spread(robots, shards) if shards else {}
    for shard in range(report_shards.check_count(shards)):
        lines += [""] + _block(
            report_shards.shard_repo(repo, shard),
            admin,
            team,
            users,
            by_shard.get(shard, []),
            shared,
            MAX_INPUT["shard"],
        )
    return "\n".join(lines) + "\n"


def _block(
    repo: str, admin: str, team: str, users: list[str], robots: list[str], shared: list[str], max_input: str
) -> list[str]:
    """One repository's rules: the admin's, every robot (``team``) reads, ``robots``
    write their own report refs, the shared users theirs but ``robots``'; at
    most ``max_input`` a push."""
    lines = [f"repo {repo}", f"    config receive.maxInputSize = {max_input}", f"    RW+ = {admin}"]
    if users:
        lines.append(f"    R = {team}")
        lines += [f"    RW+ {REPORTS}/{re.escape(robot)}$ = {robot}" for robot in robots]
    for user in shared:
        refex = re.compile(shared_refex(user))
        lines += [f"    - {REPORTS}/{re.escape(robot)}$ = {user}" for robot in robots if refex.fullmatch(robot)]
        lines.append(f"    RW+ {REPORTS}/{shared_refex(user)}$ = {user}")
    return lines


def key_file(robot: str, enrollment: bool = False) -> str:
    return f"keydir/{check_robot(robot)}{ENROLL_SUFFIX if enrollment else ''}.pub"


@dataclass(frozen=True)
class Admin:
    """How the operator reaches the gitolite server as its admin."""

    url: str  # ssh://gitolite3@host:port (no path)
    key: str  # the admin's private key
    known_hosts: str  # the server's host key, checked strictly
    admins: tuple[str, ...] = ("admin",)

    def env(self) -> dict:
        ssh = (
            f"ssh -i {shlex.quote(self.key)} -o IdentitiesOnly=yes -o BatchMode=yes "
            f"-o StrictHostKeyChecking=yes -o UserKnownHostsFile={shlex.quote(self.known_hosts)} "
            f"-o ConnectTimeout=10 {' '.join(keepalive.openssh_options(*keepalive.DEFAULT))}"
        )
        return dict(os.environ, GIT_SSH_COMMAND=ssh, GIT_TERMINAL_PROMPT="0")


def _git(admin: Admin, *args: str, cwd: str | None = None, said: list | None = None) -> str:
    try:
        done = subprocess.run(
            ["git", *args], cwd=cwd, env=admin.env(), capture_output=True, text=True, timeout=GIT_TIMEOUT
        )
    except subprocess.TimeoutExpired:
        raise GitoliteError(f"git {args[0]} to {admin.url}: no answer within {GIT_TIMEOUT} s") from None
    if done.returncode != 0:
        lines = [line for line in done.stderr.splitlines() if line.strip()]
        raise GitoliteError(f"git {args[0]} to {admin.url}: {lines[-1] if lines else f'exit {done.returncode}'}")
    if said is not None:
        said += done.stderr.splitlines()
    return done.stdout


def update(
    admin: Admin,
    repo: str,
    add: dict[str, str] | None = None,
    remove: list[str] | None = None,
    message: str = "robotfleet: robots' keys",
    shards: int = report_shards.SINGLE,
) -> bool:
    """Change the robots' keys on the server: ``add`` maps key files
    (``key_file(...)``) to public keys, ``remove`` names key files, both in
    the fleet's own key directory; the fleet's conf file is rewritten for the
    robots that then have a key there (robotfleet/pull/operator/gitolite_admin.py:
    every other line and key of the admin repository stays as it was).
    False when nothing changed; GitoliteError (one line) when the admin
    repository's layout is not one robotfleet can add to safely."""
    with tempfile.TemporaryDirectory(prefix="robotfleet-gitolite-") as tmp:
        work = os.path.join(tmp, "admin")
        _git(admin, "clone", "-q", f"{admin.url}/gitolite-admin", work)
        layout = gitolite_admin.Layout(work, repo)
        try:
            layout.check()
            moved = layout.migrate(admin.admins) if layout.old() else []
            if moved:
                where = gitolite_admin.key_dir(repo)
                message += f" (and the older layout's robots moved to {where}: {' '.join(moved)})"
            layout.keys.mkdir(parents=True, exist_ok=True)
            for path, key in (add or {}).items():
                Path(layout.keys, _in_keydir(path)).write_text(check_key(key, path) + "\n")
            for path in remove or ():
                Path(layout.keys, _in_keydir(path)).unlink(missing_ok=True)
            robots = layout.robots(admin.admins)
            layout.check_users(robots)
            layout.write(conf(repo, robots, admin.admins, shards))
        except gitolite_admin.LayoutError as error:
            raise GitoliteError(f"{admin.url}/gitolite-admin: {error}") from None
        _git(admin, "add", "-A", ".", cwd=work)
        if not _git(admin, "status", "--porcelain", cwd=work).strip():
            return False
        _git(admin, *IDENTITY, "commit", "-q", "-m", message, cwd=work)
        said: list[str] = []
        _git(admin, "push", "-q", "origin", "HEAD:master", cwd=work, said=said)
        fatal = [line.split("FATAL:", 1)[1].strip() for line in said if "FATAL:" in line]
        if fatal:  # pushed, but gitolite could not compile it (its rules stay the last ones it did): undone
            _git(admin, *IDENTITY, "revert", "--no-edit", "HEAD", cwd=work)
            _git(admin, "push", "-q", "origin", "HEAD:master", cwd=work)
            hint = (
                "; let robotfleet's rules set it: add receive.maxInputSize to GIT_CONFIG_KEYS in the "
                "server's ~/.gitolite.rc (docs/guides/pull.md)"
                if "receive.maxInputSize" in fatal[0]
                else ""
            )
            raise GitoliteError(f"{admin.url}/gitolite-admin: gitolite refused the change (undone): {fatal[0]}{hint}")
    return True


def _in_keydir(path: str) -> str:
    """A ``key_file()`` name's file in the fleet's key directory."""
    name = path.removeprefix("keydir/")
    if "/" in name or not name.endswith(".pub"):
        raise GitoliteError(f"{path}: not a key file of a robot (keydir/<robot>.pub)")
    return name


def register(
    admin: Admin, repo: str, robot: str, public_key: str, enrollment: bool = False, shards: int = report_shards.SINGLE
) -> bool:
    """Give ``robot`` read access to ``repo`` (and its ``shards`` report
    shards) and write access to its own report ref, with ``public_key``;
    registering its own key retires its enrollment key."""
    add = {key_file(robot, enrollment): public_key}
    remove = [] if enrollment else [key_file(robot, enrollment=True)]
    return update(admin, repo, add, remove, f"robotfleet: {'enrollment ' if enrollment else ''}key of {robot}", shards)
