"""roles/docker: Docker CE from Docker's apt repository (or the distribution's
engine), daemon.json, the service enabled and running, and docker_users in
the docker group (users.py)."""

from __future__ import annotations

from pyinfra.api import deploy

from robotfleet import value_kinds
from robotfleet.host import apt, aptrepo, operations
from robotfleet.host.snapshot import SnapshotQuery
from robotfleet.role import Play, Role, StatusPart
from roles.docker import daemon, hooks, plan, settings, users

DAEMON_JSON = daemon.DAEMON_JSON
PREREQUISITES = ["ca-certificates", "curl"]
KEY_PROBE = "docker_key_fingerprints"


def sources_path(data) -> str:
    return f"{aptrepo.SOURCES_DIR}/{data.docker_apt_filename}.sources"


def repository(data, os_release: dict, arch: str) -> aptrepo.Repository:
    """Docker's repository for this host, as Docker documents it."""
    dist = plan.distribution(os_release)
    return aptrepo.Repository(
        what="Docker",
        key_url=plan.key_url(data.docker_apt_key_url, data.docker_repo_url, dist),
        key_path=data.docker_apt_key_path,
        fingerprint=value_kinds.normal_fingerprint(data.docker_apt_key_fingerprint),
        fingerprint_setting="docker_apt_key_fingerprint",
        sources_name=data.docker_apt_filename,
        sources=plan.sources_text(
            plan.repo_uri(data.docker_repo_url, dist),
            plan.suite(os_release),
            data.docker_apt_release_channel,
            plan.architecture(arch),
            data.docker_apt_key_path,
        ),
        probe=KEY_PROBE,
        sha256=data.docker_apt_key_sha256,
        sha256_setting="docker_apt_key_sha256",
    )


def daemon_json(play: Play) -> str:
    """/etc/docker/daemon.json as this host gets it: docker_daemon_options,
    what the other roles add (hooks.DAEMON_OPTIONS), each DaemonSetting."""
    return plan.daemon_json(
        play.with_additions(hooks.DAEMON_OPTIONS, play.data.docker_daemon_options), settings.daemon_keys(play.data)
    )


def declare_reads(data, query: SnapshotQuery) -> None:
    packages = set(data.docker_packages) | set(data.docker_obsolete_packages) | set(PREREQUISITES)
    packages |= {"docker-ce", "gpg"} | set(data.docker_distro_packages or [])
    packages |= {name for names in plan.DISTRO_PACKAGES.values() for name in names}
    query.packages |= packages
    query.files |= {
        aptrepo.KEYRING_DIR,
        data.docker_apt_key_path,
        sources_path(data),
        "/etc/docker",
        DAEMON_JSON,
        daemon.PENDING,
        daemon.PREVIOUS,
    }
    query.files |= set(data.docker_apt_legacy_files)
    query.units.add("docker.service")
    query.commands.add("gpg")
    query.probes[KEY_PROBE] = aptrepo.key_probe(
        data.docker_apt_key_path, value_kinds.normal_fingerprint(data.docker_apt_key_fingerprint)
    )
    query.probes["dpkg_audit"] = apt.DPKG_AUDIT_PROBE
    users.declare_reads(data, query)


def steps(play: Play):
    install_docker(play)
    users.docker_users(play)


@deploy("Docker")
def install_docker(play: Play):
    data, snap = play.data, play.snapshot
    try:
        if data.docker_source == "docker":
            repo = repository(data, snap.os_release, snap.arch)
        else:
            plan.suite(snap.os_release)
            plan.architecture(snap.arch)
            packages = plan.distro_packages(snap.os_release, data.docker_distro_packages)
    except plan.PlanError as error:
        operations.fail(name="Check the host can run Docker", message=f"docker: {error}")
        return

    # A power cut or a dropped link during an earlier install left dpkg
    # half-way: finish it first, or every apt-get below refuses to run.
    apt.dpkg_repair(name="Finish an interrupted dpkg run", audit=snap.probes.get("dpkg_audit", ""))
    if data.docker_source == "docker":
        _docker_repository(play, repo)
        apt.apt_install(
            name="Install Docker CE and the compose plugin",
            packages=data.docker_packages,
            installed=snap.packages,
            versions=plan.package_versions(data.docker_packages, data.docker_version),
        )
    else:
        if snap.installed("docker-ce"):
            operations.fail(
                name="Check for Docker CE",
                message="docker: docker_source is distro but Docker CE is installed; "
                "remove docker-ce first (apt-get purge docker-ce docker-ce-cli containerd.io)",
            )
            return
        apt.apt_install(
            name="Install the distribution's Docker engine and compose",
            packages=packages,
            installed=snap.packages,
        )

    operations.directory(
        name="Docker configuration directory /etc/docker", path="/etc/docker", current=snap.files.get("/etc/docker")
    )
    operations.service(
        name="Docker enabled and running",
        unit="docker.service",
        enabled_now=snap.unit_enabled("docker.service"),
        active_now=snap.unit_active("docker.service"),
        enabled=data.docker_service_enabled,
    )
    action = data.docker_daemon_config_change
    content = daemon_json(play)
    pending = snap.files.get(daemon.PENDING) is not None
    written = daemon.daemon_json(
        name=f"Write /etc/docker/daemon.json and {action} Docker "
        "(the previous file comes back if Docker does not start)",
        content=content,
        current=snap.files.get(DAEMON_JSON),
        action=action,
        timeout=data.docker_restart_timeout,
        pending=pending,
        previous=snap.files.get(daemon.PREVIOUS),
    )
    if daemon.restarts_docker(content, snap.files.get(DAEMON_JSON), pending):
        play.announce(hooks.RESTARTED, written)


def _docker_repository(play: Play, repo: aptrepo.Repository):
    data, snap = play.data, play.snapshot
    prerequisites = list(PREREQUISITES)
    if repo.fingerprint and not snap.commands.get("gpg"):
        prerequisites.append("gpg")
    apt.apt_install(
        name="Install apt prerequisites",
        packages=prerequisites,
        installed=snap.packages,
        update_first=True,
    )
    legacy = [p for p in data.docker_apt_legacy_files if p not in (data.docker_apt_key_path, sources_path(data))]
    legacy_removed = operations.absent(name="Remove legacy Docker apt files", paths=legacy, present=snap.files)
    apt.apt_remove(
        name="Remove conflicting packages",
        packages=plan.obsolete_to_remove(data.docker_obsolete_packages, snap.packages),
    )
    aptrepo.set_up(repo, snap, legacy_removed)


STATUS = StatusPart(
    command=lambda data: "docker version -f '{{.Server.Version}}'",
    cells=lambda output: {"docker": output.strip() or None},
    columns=(("docker", "DOCKER"),),
    wide=("docker",),
    order=10,
    watch=lambda data: ["/usr/bin/dockerd"],  # an upgrade replaces it
)

ROLE = Role(
    name="docker",
    doc="Docker CE and the compose plugin from Docker's apt repository (or the distribution's engine), daemon.json, "
    "the declared users in the docker group (never created).",
    settings=settings.SETTINGS,
    rules=settings.rules,
    renamed=settings.RENAMED,
    reads=declare_reads,
    steps=steps,
    status=STATUS,
)
