"""Pull mode on the lab: a deploy repository whose fleet file marks the
robots `pull_enabled`, its fleet remote on the lab's git server, release keys, and
the commands the operator runs (publish, halt, status) with them.

The fleet file robots read comes from the release's code, so it is the
lab's fleet (inventories/lab.yaml) with the lab's values filled in, its
images pinned by digest (this machine reaches the lab registry on
127.0.0.1, the robots by its name on the lab network: a digest is the same
through both), and the pull settings in robots' vars.
"""

from __future__ import annotations

import json
import os
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import yaml

from . import gitserver, state
from .engine import REPO_ROOT, LabError

FLEET = "inventories/pull-lab.yaml"
ROBOTFLEET = [sys.executable, "-m", "robotfleet"]


def digest_of(lab: dict, repository: str, tag: str) -> str:
    from roles.payload.registry import Registry

    local = lab["registry_local"]
    return Registry(local, [local], None).manifest(repository, tag)[2]


def pinned(lab: dict, repository: str, tag: str) -> str:
    """The image as the robots name it, pinned by its digest."""
    return f"{lab['registry']}/{repository}:{tag}@{digest_of(lab, repository, tag)}"


def lab_fleet(lab: dict) -> dict:
    """inventories/lab.yaml with the lab's values filled in (what inventories/lab.py fills in)."""
    text = (REPO_ROOT / "inventories" / "lab.yaml").read_text()
    manifest = (
        json.loads((Path(lab["mirror_dir"]) / "manifest.json").read_text())
        if (Path(lab["mirror_dir"]) / "manifest.json").exists()
        else json.loads((Path(lab["mirror_dir"]).parent / "manifest.json").read_text())
    )
    for key, value in {
        "@registry_local@": lab["registry_local"],
        "@registry@": lab["registry"],
        "@mirror@": lab["mirror_url"],
        "@mirror_fingerprint@": manifest["fingerprint"],
    }.items():
        text = text.replace(key, value)
    return yaml.safe_load(text)


def fleet_text(lab: dict, payload_tag: str = "1.0", robots: list[str] | None = None, **pull) -> str:
    """inventories/lab.yaml for pull robots: the lab's values filled in,
    only ``robots`` (default: the lab's native robots), pull settings."""
    fleet = lab_fleet(lab)
    git = lab["git"]
    ed25519 = [" ".join(k.split()[:2]) for k in git["host_keys"] if k.startswith("ssh-ed25519")]
    names = robots or [h["name"] for h in lab["hosts"] if h["group"] == "robots" and h["arch"] == "amd64"]
    fleet["robots"]["hosts"] = {name: fleet["robots"]["hosts"].get(name) or {} for name in names}
    fleet["all"]["vars"]["payload_image"] = pinned(lab, "ros/payload", payload_tag)
    fleet["robots"]["vars"].update(
        {
            "pull_enabled": True,
            "pull_remote": gitserver.robot_url(git),
            "pull_remote_host_keys": ed25519,
            "pull_interval": 30,
            "pull_jitter": 2,
            "pull_boot_delay": 5,
            "pull_min_free_mb": 64,
            "pull_platform": "cp313-x86_64",
            **pull,
        }
    )
    # JSON is YAML 1.2, and quotes every string ("0825" stays text).
    return "# The lab's fleet in pull mode (tests/lab/pullfleet.py).\n" + json.dumps(fleet, indent=1) + "\n"


def copy_tracked(destination: Path) -> None:
    """This checkout's tracked files, as they are now, copied into ``destination``."""
    files = (
        subprocess.run(["git", "-C", str(REPO_ROOT), "ls-files", "-z"], capture_output=True, check=True)
        .stdout.decode()
        .split("\0")
    )
    for name in filter(None, files):
        source = REPO_ROOT / name
        if source.is_file():
            (destination / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, destination / name)


class Operator:
    """The operator's side of pull mode on one lab: a deploy repository in
    ``base``/deploy (this checkout's tracked files), its fleet remote on the
    lab's git server, release keys in ``base``/keys."""

    def __init__(self, prefix: str, base: Path):
        self.lab = state.load(prefix)
        if "git" not in self.lab:
            raise LabError(f"lab '{prefix}' has no git server (python3 -m tests.lab up --git-server)")
        self.prefix, self.base = prefix, base
        self.repo = base / "deploy"
        self.keys = base / "keys"
        self.git = self.lab["git"]

    def env(self, **more) -> dict:
        ssh = (
            f"ssh -F /dev/null -i {shlex.quote(self.lab['ssh_key'])} -o IdentitiesOnly=yes -o BatchMode=yes "
            f"-o StrictHostKeyChecking=yes -o UserKnownHostsFile={shlex.quote(self.git['known_hosts'])}"
        )
        return dict(
            os.environ,
            GIT_SSH_COMMAND=ssh,
            ROBOTFLEET_KEYS=str(self.keys),
            GIT_TERMINAL_PROMPT="0",
            ROBOTFLEET_RELEASES_CLONE=str(self.base / "releases"),
            ROBOT_LAB_PREFIX=self.prefix,
            ROBOTFLEET_ENROLLMENTS=str(self.base / "enrollments.json"),
            XDG_CACHE_HOME=str(REPO_ROOT / ".lab" / "cache" / "pull"),
            **more,
        )

    def _git(self, *args: str) -> str:
        done = subprocess.run(["git", "-C", str(self.repo), *args], capture_output=True, text=True, env=self.env())
        if done.returncode:
            raise LabError(f"git {' '.join(args[:2])}: {done.stderr.strip()[-300:]}")
        return done.stdout

    def setup(self) -> None:
        """The deploy repository (once) and the release keys (once)."""
        if not (self.repo / ".git").exists():
            self.repo.mkdir(parents=True, exist_ok=True)
            self._git("init", "-q", "-b", "main")
            # the fleet's releases remote, named once (a deploy repository's own origin is refused by default)
            self._git("config", "robotfleet.remote", gitserver.local_url(self.git))
            (self.repo / ".lab").symlink_to(REPO_ROOT / ".lab")  # inventories/lab.py reads the running lab there
        if not (self.keys / "online.key").exists():
            self.robotfleet("keys", "init", "--keys", str(self.keys))

    def sync(self) -> None:
        """The deploy repository's files made this checkout's (its tracked files, as they are now)."""
        copy_tracked(self.repo)

    def commit(self, fleet: str, message: str) -> str:
        self.sync()
        (self.repo / FLEET).write_text(fleet)
        self._git("add", "-A")
        self._git(
            "-c", "user.name=lab", "-c", "user.email=lab@localhost", "commit", "-q", "--allow-empty", "-m", message
        )
        return self._git("rev-parse", "HEAD").strip()

    def robotfleet(self, *args: str, check: bool = True, env: dict | None = None) -> subprocess.CompletedProcess:
        done = subprocess.run(
            [*ROBOTFLEET, *args],
            cwd=self.repo if (self.repo / ".git").exists() else REPO_ROOT,
            capture_output=True,
            text=True,
            env=env or self.env(),
            timeout=900,
        )
        if check and done.returncode:
            raise LabError(
                f"robotfleet {' '.join(args[:2])} exited {done.returncode}: "
                f"{(done.stderr or done.stdout).strip()[-800:]}"
            )
        return done

    def rollout(self, fleet: str, message: str, *options: str) -> subprocess.CompletedProcess:
        """robotfleet rollout over the lab's pull robots (publish, then follow their reports)."""
        self.commit(fleet, message)
        env = self.env(ROBOT_LAB_FLEET=str(self.repo / FLEET))
        return self.robotfleet(
            "rollout",
            "inventories/lab.py",
            "--fleet",
            FLEET,
            "--keys",
            str(self.keys),
            "-y",
            *options,
            check=False,
            env=env,
        )

    def status(self, *options: str) -> subprocess.CompletedProcess:
        env = self.env(ROBOT_LAB_FLEET=str(self.repo / FLEET))
        return self.robotfleet("status", "inventories/lab.py", *options, check=False, env=env)

    def publish(self, fleet: str, message: str, *options: str) -> subprocess.CompletedProcess:
        self.commit(fleet, message)
        wheels = (
            [] if "--no-wheels" in options else ["--wheel-cache", str(REPO_ROOT / ".lab" / "cache" / "pull-wheels")]
        )
        return self.robotfleet(
            "publish", FLEET, "--checkout", str(self.repo), "--keys", str(self.keys), *wheels, *options
        )

    def reports(self) -> dict[str, dict]:
        """Every robot's last report on the lab's git server (as the operator reads them)."""
        from robotfleet.pull.protocol import report_store

        cache = self.base / "reports-cache"
        if not (cache / "HEAD").exists():
            subprocess.run(["git", "init", "-q", "--bare", str(cache)], check=True)
        done = subprocess.run(
            [
                "git",
                "-C",
                str(cache),
                "fetch",
                "-q",
                "--prune",
                gitserver.local_url(self.git),
                "+refs/reports/*:refs/reports/*",
            ],
            capture_output=True,
            text=True,
            env=self.env(),
        )
        if done.returncode:
            raise LabError(f"git fetch of the reports: {done.stderr.strip()[-300:]}")
        return report_store.read_all(cache)

    def admin_options(self) -> list[str]:
        """robotfleet bundle / pull-enroll's options for the lab's gitolite (the lab key is its admin)."""
        return [
            "--admin",
            f"ssh://{self.git['user']}@127.0.0.1:{self.git['port']}",
            "--admin-key",
            self.lab["ssh_key"],
            "--admin-known-hosts",
            self.git["known_hosts"],
        ]

    def remote(self) -> list[str]:
        return ["--remote", gitserver.local_url(self.git)]

    def register_robots(self, robots: list[str]) -> None:
        """Each robot's own key (made on it by the pull role) with gitolite."""
        for robot in robots:
            code, out = state.exec_in(self.prefix, robot, "cat /etc/robot-pull/id_ed25519.pub")
            if code != 0:
                raise LabError(f"{robot}: no key for the fleet remote ({out.strip()})")
            gitserver.register_robot(self.prefix, robot, out)


class Attacks:
    """What a compromised git server or mirror could serve the robots: each
    writes the releases branch as the admin (force push), as such a server
    could; ``restore`` puts the good branch back."""

    def __init__(self, operator: Operator):
        self.op = operator
        self.work = operator.base / "attack"
        self.url = gitserver.local_url(operator.git)

    def _git(self, *args: str) -> str:
        done = subprocess.run(["git", "-C", str(self.work), *args], capture_output=True, text=True, env=self.op.env())
        if done.returncode:
            raise LabError(f"git {' '.join(args[:2])}: {done.stderr.strip()[-300:]}")
        return done.stdout

    def checkout(self) -> str:
        """The releases branch as the remote has it now, in a scratch clone; its commit."""
        if not (self.work / ".git").exists():
            self.work.mkdir(parents=True)
            self._git("init", "-q")
        self._git("fetch", "-q", self.url, "+refs/heads/robotfleet/releases:refs/remotes/fleet/releases")
        self._git("checkout", "-q", "--force", "--detach", "refs/remotes/fleet/releases")
        self._git("clean", "-q", "-dfx")
        return self._git("rev-parse", "HEAD").strip()

    def push(self, message: str) -> None:
        self._git("add", "-A", ".")
        self._git(
            "-c", "user.name=attacker", "-c", "user.email=a@localhost", "commit", "-q", "--allow-empty", "-m", message
        )
        self._git("push", "-q", "--force", self.url, "HEAD:refs/heads/robotfleet/releases")

    def restore(self, commit: str) -> None:
        self._git("push", "-q", "--force", self.url, f"{commit}:refs/heads/robotfleet/releases")

    def tamper(self) -> None:
        """The current release record, changed after it was signed (another image digest)."""
        from robotfleet.pull.operator.repository import Repository

        self.checkout()
        record = Repository(self.work).blob("release.json")
        data = json.loads(record.read_text())
        for pins in data["images"].values():
            for ref in pins:
                pins[ref] = "sha256:" + "6" * 64
        record.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")
        self.push("tampered record")

    def replay(self, old_commit: str) -> None:
        """An older release, as it was signed then."""
        self.restore(old_commit)

    def expire(self) -> None:
        """A timestamp signed with the real key, valid only until yesterday."""
        import datetime

        from robotfleet.pull.operator.keys import KeyDir
        from robotfleet.pull.operator.repository import Expiry, Repository

        self.checkout()
        past = datetime.datetime.now(datetime.timezone.utc).replace(microsecond=0) - datetime.timedelta(days=2)
        Repository(self.work).renew(
            KeyDir(self.op.keys).signer("online"), Expiry(timestamp=datetime.timedelta(days=1)), past
        )
        self.push("expired timestamp")

    def other_key(self) -> None:
        """The current release re-signed by a key the robots do not trust
        (a stolen copy re-signed; no publish needed to make one)."""
        from tuf.api.metadata import Metadata

        from robotfleet.pull.operator.keys import KeyDir

        other = KeyDir(self.op.base / "other-keys")
        if not other.has("online"):
            other.path.mkdir(mode=0o700, exist_ok=True)
            other.generate("online")
        self.checkout()
        path = self.work / "metadata" / "timestamp.json"
        timestamp = Metadata.from_file(str(path))
        timestamp.signed.version += 1
        timestamp.signatures.clear()
        timestamp.sign(other.signer("online"))
        timestamp.to_file(str(path))
        self.push("signed by another key")
