"""Test fixtures: what a successful run of the docker role leaves on a host."""

from robotfleet.host import aptrepo
from robotfleet.host.fixtures import file_state
from robotfleet.host.snapshot import FileState
from roles import docker


def converged(play, host: str) -> None:
    data, snap = play.data, play.snapshot
    snap.packages.update({p: "1" for p in data.docker_packages})
    repo = docker.repository(data, snap.os_release, snap.arch)
    snap.files.update(
        {
            "/etc/apt/keyrings": FileState("dir", None, "755", "root", "root"),
            repo.key_path: FileState("file", "f" * 64, "644", "root", "root"),
            repo.sources_path: file_state(repo.sources),
            "/etc/docker": FileState("dir", None, "755", "root", "root"),
            docker.DAEMON_JSON: file_state(docker.daemon_json(play), mode=docker.daemon.MODE),
        }
    )
    snap.probes[docker.KEY_PROBE] = f"{repo.fingerprint}\n{aptrepo.CANONICAL}\n" if repo.fingerprint else ""
    snap.units["docker.service"] = ("enabled", "active")
    for user in data.docker_users:
        snap.users[user] = [user, "docker"]
