"""Pull mode's lab, shared by the pull modules of the end-to-end layer
(tests/e2e/test_pull*.py): the robots, their fast settings, a check started
now, the operator's side (``Pull``) and what they ask of the fleet remote."""

from __future__ import annotations

import subprocess
import threading
from pathlib import Path

ROBOTS = ["robot1", "robot2", "robot3"]
FIRST_BOOT = "robot4"
ALL = ROBOTS + [FIRST_BOOT]
# git on a robot as the robot's agent reaches the fleet remote: its own key, the pinned host key
ROBOT_GIT_SSH = (
    "GIT_SSH_COMMAND='ssh -F /dev/null -i /etc/robot-pull/id_ed25519 -o IdentitiesOnly=yes "
    "-o UserKnownHostsFile=/etc/robot-pull/known_hosts -o HostKeyAlias=robotfleet-remote' "
)
# Short health windows keep the module fast; the robots' timers at an hour check only at boot and
# after the agent is installed (OnBootSec, OnActiveSec): every other check is one a test starts when
# it waits on it (``Pull.trigger``), not one every 10 s on four robots (~0.45 s of a robot's CPU each).
FAST = {"payload_health_timeout": 20, "payload_stable_seconds": 2, "pull_interval": 3600, "pull_jitter": 0}
# A robot's check started now (systemctl start waits for the oneshot); one its timer started is waited for
# first (a start would only join it).
CHECK_NOW = (
    'while [ "$(systemctl show -p ActiveState --value robot-pull.service)" = activating ]; '
    "do sleep 0.5; done; systemctl start robot-pull.service"
)


class Pull:
    """The operator's side of pull mode over the lab (tests/lab/pullfleet.py),
    the fleet files it publishes, the robots' checks and their reports."""

    def __init__(self, lab, base: Path):
        from tests.lab import pullfleet

        self.lab, self.pullfleet = lab, pullfleet
        self.op = pullfleet.Operator(lab.prefix, base)
        self.attacks = pullfleet.Attacks(self.op)

    def fleet(self, tag: str, robots=ALL, **more) -> str:
        return self.pullfleet.fleet_text(self.op.lab, payload_tag=tag, robots=robots, **FAST, **more)

    def trigger(self, robots) -> None:
        """A check starting now on each robot, at once (systemctl start waits
        for the oneshot; a check the timer started earlier is waited for
        first: a start would only join it)."""
        threads = [threading.Thread(target=self.lab.sh, args=(r, CHECK_NOW)) for r in robots]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()

    def reports(self) -> dict:
        return self.op.reports()

    def head(self) -> str | None:
        """The fleet remote's releases branch (its commit), None before the first publish."""
        from tests.lab import gitserver

        done = subprocess.run(
            ["git", "ls-remote", gitserver.local_url(self.op.git), "refs/heads/robotfleet/releases"],
            capture_output=True,
            text=True,
            env=self.op.env(),
            check=True,
        )
        return done.stdout.split()[0] if done.stdout.strip() else None

    def trigger_once_published(self, before: str | None, robots, seconds: float = 300) -> None:
        """A check on each of ``robots`` once a release newer than the branch at
        ``before`` is on the fleet remote (a rollout running beside publishes it)."""
        from tests.e2e.conftest import wait_for

        wait_for(lambda: self.head() != before, seconds, "the release on the fleet remote", interval=1)
        self.trigger(robots)


def ssh_error(lab, host: str) -> str | None:
    """Why the operator's side cannot log in to ``host`` over SSH (strict host keys), None if it can."""
    from tests.lab import state
    from tests.lab.hosts import _ssh_login_error

    port = next(h["port"] for h in state.load(lab.prefix)["hosts"] if h["name"] == host)
    return _ssh_login_error(port, Path(lab.state["ssh_key"]), Path(lab.state["known_hosts"]))


def by_digest(ref: str) -> str:
    """repository:tag@digest -> repository@digest (what `docker image inspect` finds by digest)."""
    name, digest = ref.split("@", 1)
    slash, colon = name.rfind("/"), name.rfind(":")
    return f"{name[:colon] if colon > slash else name}@{digest}"


def remote_refs(world) -> list[str]:
    from tests.lab import gitserver

    done = subprocess.run(
        ["git", "ls-remote", gitserver.local_url(world.op.git)],
        capture_output=True,
        text=True,
        env=world.op.env(),
        check=True,
    )
    return [
        line.split()[1]
        for line in done.stdout.splitlines()
        if line.split()[1] == "refs/heads/robotfleet/releases" or line.split()[1].startswith("refs/reports/")
    ]


def clear_remote(world) -> None:
    """No releases branch and no report on the fleet remote (as the admin)."""
    from tests.lab import gitserver

    refs = remote_refs(world)
    if refs:
        subprocess.run(
            ["git", "push", "-q", gitserver.local_url(world.op.git), *(f":{ref}" for ref in refs)],
            env=world.op.env(),
            check=True,
            capture_output=True,
        )
