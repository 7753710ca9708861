"""A fleet of pull robots on the lab's gitolite, for the git server's
benchmarks (reports_scale.py, git_load.py): only the lab's git server runs
(tests/lab/hosts.py ``git_server_alone``), every robot is a gitolite user
with its own key and the rules ``pull-enroll`` writes
(robotfleet/pull/operator/gitolite.py), and each robot's report is seeded
into the server's repositories with ``git fast-import`` as the server's user
(a commit holding a valid report.json per robot, as the agent pushes it),
and with shards the server's read copy seeded from them (its hook,
files/git-server/post-receive, which the lab installs as the guide says).
A robot is then played by robotfleet's own transport with that robot's key.
"""

from __future__ import annotations

import datetime
import io
import os
import subprocess
import tarfile
import time
from pathlib import Path

RELEASES = "refs/heads/robotfleet/releases"
NAME = "robot-{:05d}"
REPOSITORIES = "/var/lib/gitolite3/repositories"
SEED_DIR = "/tmp/bench-seed"
HOOK = "/var/lib/gitolite3/.gitolite/hooks/common/post-receive"


def robots(count: int) -> list[str]:
    return [NAME.format(i) for i in range(count)]


def keypair() -> tuple[bytes, str]:
    """A robot's key: (private key, OpenSSH format; public key line)."""
    from cryptography.hazmat.primitives import serialization
    from cryptography.hazmat.primitives.asymmetric import ed25519

    key = ed25519.Ed25519PrivateKey.generate()
    private = key.private_bytes(
        serialization.Encoding.PEM, serialization.PrivateFormat.OpenSSH, serialization.NoEncryption()
    )
    public = key.public_key().public_bytes(serialization.Encoding.OpenSSH, serialization.PublicFormat.OpenSSH)
    return private, public.decode()


def utc(seconds: float) -> datetime.datetime:
    return datetime.datetime.fromtimestamp(int(seconds), datetime.timezone.utc)


def report(robot: str) -> bytes:
    """A robot's report as its agent pushes it after an idle check."""
    from robotfleet.pull.protocol import reports

    return reports.to_bytes(reports.build(robot, utc(time.time()), "up-to-date"))


def fast_import(robots_here: list[str], releases: bool) -> bytes:
    """A ``git fast-import`` stream: a report commit for each robot (and a
    releases branch)."""
    moment = int(time.time())
    stream = []
    for index, robot in enumerate(robots_here):
        data = report(robot)
        stream.append(b"blob\nmark :%d\ndata %d\n%s\n" % (2 * index + 1, len(data), data))
        stream.append(
            b"commit refs/reports/%s\nmark :%d\ncommitter bench <bench@lab> %d +0000\ndata 6\nreport\n"
            b"M 100644 :%d report.json\n\n" % (robot.encode(), 2 * index + 2, moment, 2 * index + 1)
        )
    if releases:
        stream.append(
            b"blob\nmark :999999999\ndata 3\nv1\n\ncommit %s\ncommitter bench <bench@lab> %d +0000\n"
            b"data 8\nrelease\nM 100644 :999999999 metadata/timestamp.json\n\n" % (RELEASES.encode(), moment)
        )
    return b"".join(stream)


class Server:
    """The lab's gitolite alone, as its admin and as each robot."""

    def __init__(self, prefix: str, base: Path):
        from robotfleet.pull.operator import gitolite
        from tests.lab import gitserver, hosts

        gitolite.GIT_TIMEOUT = 1800  # a gitolite-admin push compiling 10,000 keys takes minutes (a kept lab's too)
        self.git, key = hosts.git_server_alone(prefix)
        self.admin = gitserver.admin(self.git, key)
        self.url = gitserver.local_url(self.git)  # ssh://gitolite3@127.0.0.1:PORT/fleet
        self.base = base
        self.keys: dict[str, tuple[bytes, str]] = {}
        self.registered: tuple[int, int] | None = None
        os.environ["GIT_SSH_COMMAND"] = self.admin.env()["GIT_SSH_COMMAND"]  # the operator's reads

    def sh(self, script: str, stdin: bytes | None = None, user: str = "gitolite3") -> str:
        done = subprocess.run(
            ["docker", "exec", "-i", "-u", user, self.git["container"], "sh", "-c", script],
            input=stdin,
            capture_output=True,
            timeout=1800,
        )
        if done.returncode:
            raise SystemExit(f"bench: on the git server: {script[:80]}: {done.stderr.decode()[-500:]}")
        return done.stdout.decode()

    def register(self, names: list[str], shards: int) -> None:
        """Every robot a gitolite user with its own key; the rules for ``shards``."""
        from robotfleet.pull.operator import gitolite

        if self.registered == (len(names), shards):
            return
        for robot in names:
            self.keys.setdefault(robot, keypair())
        add = {gitolite.key_file(robot): self.keys[robot][1] for robot in names}
        started = time.monotonic()
        gitolite.update(
            self.admin, self.git["repo"], add, message=f"bench: {len(names)} robots, {shards} shards", shards=shards
        )
        self.registered = (len(names), shards)
        print(
            f"bench: {len(names)} robots registered, {shards} shards ({time.monotonic() - started:.0f} s)", flush=True
        )

    def seed(self, by_repo: dict[str, list[str]]) -> None:
        """Exactly these robots' reports in each repository (and a releases
        branch in the fleet's): one ``docker exec`` for all of them."""
        archive = io.BytesIO()
        with tarfile.open(fileobj=archive, mode="w") as tar:
            for repo, names in by_repo.items():
                data = fast_import(names, releases=repo == self.git["repo"])
                info = tarfile.TarInfo(repo)
                info.size = len(data)
                tar.addfile(info, io.BytesIO(data))
        self.sh(
            f"set -e; rm -rf {SEED_DIR}; mkdir -p {SEED_DIR}; tar -x -C {SEED_DIR}; "
            f"for name in $(ls {SEED_DIR}); do where={REPOSITORIES}/$name.git; "
            "git -C $where for-each-ref --format='delete %(refname)' refs/reports/ | "
            "git -C $where update-ref --stdin; "
            f"git -C $where fast-import --quiet --force < {SEED_DIR}/$name; "
            "git -C $where pack-refs --all; done; "
            f"rm -rf {SEED_DIR}",
            stdin=archive.getvalue(),
        )

    def layout(self, names: list[str], shards: int) -> None:
        """The server holding ``names``' reports in ``shards`` shards (0: in the fleet repository)."""
        from robotfleet.pull.protocol import report_shards

        self.register(names, shards)
        spread = report_shards.spread(names, shards)
        by_repo = {self.git["repo"]: names if shards == 0 else []}
        by_repo.update(
            {report_shards.shard_repo(self.git["repo"], shard): spread.get(shard, []) for shard in range(shards)}
        )
        self.seed(by_repo)
        if shards:  # the server's read copy of the shards (its hook, installed by the lab as the guide says)
            self.sh(f"sh {HOOK} --seed {REPOSITORIES}/{self.git['repo']}.git")

    def drop_copy(self) -> None:
        """The fleet remote without its read copy: readers fetch every shard."""
        self.sh(f"git -C {REPOSITORIES}/{self.git['repo']}.git update-ref -d refs/report-copy")

    def cpu_seconds(self) -> float:
        """The server container's CPU time so far: its cgroup's (v1 cpuacct
        or v2 cpu.stat, whichever this machine has), read on the server."""
        text = self.sh(
            "cg=$(sed -n 's/^[0-9]*:\\(cpu,cpuacct\\|cpuacct,cpu\\|cpuacct\\):\\(.*\\)/\\2/p' "
            "/proc/1/cgroup | head -n1); "
            "for f in /sys/fs/cgroup/cpu,cpuacct$cg/cpuacct.usage /sys/fs/cgroup/cpuacct$cg/cpuacct.usage; "
            "do [ -r $f ] && { echo ns $(cat $f); exit 0; }; done; "
            "cg=$(sed -n 's/^0::\\(.*\\)/\\1/p' /proc/1/cgroup); "
            "for f in /sys/fs/cgroup/unified$cg/cpu.stat /sys/fs/cgroup$cg/cpu.stat; "
            "do [ -r $f ] && { echo us $(sed -n 's/^usage_usec //p' $f); exit 0; }; done; exit 1"
        )
        unit, value = text.split()
        return int(value) / (1e9 if unit == "ns" else 1e6)

    def etc(self, robot: str) -> str:
        """The robot's configuration directory: its key, the server's pinned host key."""
        from robotfleet.pull.protocol import agent_files

        where = self.base / "etc" / robot
        if not where.exists():
            where.mkdir(parents=True)
            key = where / "id_ed25519"
            key.write_bytes(self.keys[robot][0])
            key.chmod(0o600)
            pinned = [k for k in self.git["host_keys"] if k.startswith("ssh-ed25519 ")]  # as the guides pin it
            (where / "known_hosts").write_text(
                "".join(f"{agent_files.HOST_KEY_ALIAS} {' '.join(k.split()[:2])}\n" for k in pinned)
            )
        return str(where)

    def remote(self, robot: str, repo: Path, shards: int, mirror: tuple[str, Path] | None = None):
        """The fleet remote as ``robot`` reaches it (robotfleet's transport), from
        ``repo``; with ``mirror`` (its URL and CA: https_mirror.py), the releases
        from there and the reports pushed here, as pull_report_remote says."""
        from robotfleet.pull.robot import transport

        etc = self.etc(robot)
        if mirror is None:
            return transport.Remote(self.url, repo, etc, timeout=300, shards=shards)
        ca = Path(etc) / "remote-ca.pem"
        if not ca.exists():
            ca.write_bytes(mirror[1].read_bytes())
        return transport.Remote(mirror[0], repo, etc, timeout=300, report_url=self.url, shards=shards)
