"""roles/docker: Docker CE from Docker's apt repository (or the distribution's
engine), daemon.json, and the service enabled and running."""

from __future__ import annotations

import shlex

from pyinfra import host
from pyinfra.api import deploy
from pyinfra.operations.util import any_changed

from roles import operations
from roles.docker import plan
from roles.hoststate import Snapshot, SnapshotQuery

KEYRING_DIR = "/etc/apt/keyrings"
DAEMON_JSON = "/etc/docker/daemon.json"
PREREQUISITES = ["ca-certificates", "curl"]
VALIDATE_DAEMON_JSON = (
    "if dockerd --help 2>&1 | grep -q -- '--validate'; then "
    "dockerd --validate --config-file {} >/dev/null; fi"
)


def sources_path(data) -> str:
    return f"/etc/apt/sources.list.d/{data.docker_apt_filename}.sources"


def fingerprints_of(path: str) -> str:
    """Shell pipeline printing the fingerprints of the primary keys in key file
    ``path`` (a shell word, already quoted), one a line, using the throwaway
    GNUPGHOME ``$h``.  Subkeys are left out: they belong to their primary key."""
    return (
        f"GNUPGHOME=$h gpg --batch --show-keys --with-colons {path} 2>/dev/null"
        " | awk -F: '$1==\"pub\"{p=1;next} p&&$1==\"fpr\"{print $10} {p=0}'"
    )


def key_fingerprints_probe(path: str) -> str:
    p = shlex.quote(path)
    return f'[ -f {p} ] && command -v gpg >/dev/null && h=$(mktemp -d) && {fingerprints_of(p)}; rm -rf "$h"'


def declare_reads(data, query: SnapshotQuery) -> None:
    packages = set(data.docker_packages) | set(data.docker_obsolete_packages) | set(PREREQUISITES)
    packages |= {"docker-ce", "gpg"} | set(data.docker_distro_packages or [])
    packages |= {name for names in plan.DISTRO_PACKAGES.values() for name in names}
    query.packages |= packages
    query.files |= {KEYRING_DIR, data.docker_apt_key_path, sources_path(data), "/etc/docker", DAEMON_JSON}
    query.files |= set(data.docker_apt_legacy_files)
    query.units.add("docker.service")
    query.commands.add("gpg")
    query.probes["docker_key_fingerprints"] = key_fingerprints_probe(data.docker_apt_key_path)


def key_download_script(url: str, dest: str, fingerprint: str | None, sha256: str | None) -> str:
    """Fetch the key to a temp file, verify it, and only then move it in place.

    With a fingerprint pin the file must hold exactly that one primary key:
    apt trusts every key of a Signed-By keyring, so a second key beside
    Docker's would sign packages too.  A keyring already on the host holding
    more than one key is removed whatever the download gives (fail closed).
    Values reach the messages through shell variables, never as code."""
    q = shlex.quote
    lines = [
        "set -e",
        f"dest={q(dest)}",
        f"url={q(url)}",
        'tmp=$(mktemp "$(dirname "$dest")/.robotprov.XXXXXX")',
        "h=$(mktemp -d)",
        "trap 'rm -f \"$tmp\"; rm -rf \"$h\"' EXIT",
    ]
    if fingerprint:
        lines += [
            f"pin={q(fingerprint)}",
            'if [ -f "$dest" ] && [ "$(' + fingerprints_of('"$dest"') + ' | wc -l)" -gt 1 ]; then',
            '  rm -f "$dest"; echo "$dest held more than one key; removed" >&2',
            "fi",
        ]
    lines.append(
        'curl -fsSL --retry 3 --connect-timeout 20 "$url" -o "$tmp" || '
        '{ echo "cannot download the Docker apt key from $url" >&2; exit 1; }'
    )
    if sha256:
        lines += [
            f"want={q(sha256)}",
            'got=$(sha256sum < "$tmp" | cut -d" " -f1); '
            '[ "$got" = "$want" ] || { echo "Docker apt key from $url: sha256 $got does not match '
            'docker_apt_key_sha256 $want; key not installed" >&2; exit 1; }',
        ]
    if fingerprint:
        lines += [
            "fprs=$(" + fingerprints_of('"$tmp"') + ")",
            'count=$(printf "%s\n" "$fprs" | grep -c . || true)',
            'printf "%s\n" "$fprs" | grep -qx "$pin" || { echo "Docker apt key from $url: fingerprint '
            '$(echo $fprs) does not match docker_apt_key_fingerprint $pin; key not installed" >&2; exit 1; }',
            '[ "$count" -eq 1 ] || { echo "Docker apt key from $url: holds $count keys ($(echo $fprs)); '
            'only docker_apt_key_fingerprint $pin may be in it; key not installed" >&2; exit 1; }',
        ]
    lines += ['chmod 644 "$tmp"', 'mv -fT "$tmp" "$dest"']
    return "\n".join(lines)


def key_is_current(snap: Snapshot, path: str, fingerprint: str | None, sha256: str | None) -> bool:
    """In place, 0644, and (when pinned) holding exactly the pinned key."""
    current = snap.files.get(path)
    if current is None or current.kind != "file" or current.mode != "644":
        return False
    if sha256 and current.sha256 != sha256:
        return False
    if fingerprint and snap.probes.get("docker_key_fingerprints", "").split() != [fingerprint]:
        return False
    return True


@operations.operation()
def apt_key(url: str, path: str, fingerprint: str | None, sha256: str | None, up_to_date: bool):
    if up_to_date:
        host.noop(f"{path} is in place")
        return
    yield operations.shell(key_download_script(url, path, fingerprint, sha256))


@deploy("Docker")
def install_docker(snap: Snapshot):
    data = host.data
    try:
        dist = plan.distribution(snap.os_release)
        codename = plan.suite(snap.os_release)
        arch = plan.architecture(snap.arch)
        if data.docker_source == "distro":
            packages = plan.distro_packages(snap.os_release, data.docker_distro_packages)
    except plan.PlanError as error:
        operations.fail(name="Check the host can run Docker", message=f"docker: {error}")
        return

    if data.docker_source == "docker":
        _docker_repository(snap, data, dist, codename, arch)
        operations.apt_install(
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
        operations.apt_install(
            name="Install the distribution's Docker engine and compose",
            packages=packages,
            installed=snap.packages,
        )

    operations.directory(name="Docker configuration directory /etc/docker", path="/etc/docker", current=snap.files.get("/etc/docker"))
    daemon = operations.file(
        name="Write /etc/docker/daemon.json",
        path=DAEMON_JSON,
        content=plan.daemon_json(
            data.docker_daemon_options, data.docker_registry_mirrors, data.docker_insecure_registries
        ),
        current=snap.files.get(DAEMON_JSON),
        validate=VALIDATE_DAEMON_JSON,
    )
    operations.service(
        name="Docker enabled and running",
        unit="docker.service",
        enabled_now=snap.unit_enabled("docker.service"),
        active_now=snap.unit_active("docker.service"),
        enabled=data.docker_service_enabled,
    )
    action = "reload" if data.docker_restart_handler_state == "reloaded" else "restart"
    operations.run(
        name=f"{action.capitalize()} Docker for the new daemon.json",
        script=f"systemctl {action} docker.service",
        _if=daemon.did_change,
    )


def _docker_repository(snap: Snapshot, data, dist: str, codename: str, arch: str):
    fingerprint = plan.normalise_fingerprint(data.docker_apt_key_fingerprint)
    prerequisites = list(PREREQUISITES)
    if fingerprint and not snap.commands.get("gpg"):
        prerequisites.append("gpg")
    operations.apt_install(
        name="Install apt prerequisites",
        packages=prerequisites,
        installed=snap.packages,
        update_first=True,
    )
    legacy = [p for p in data.docker_apt_legacy_files if p not in (data.docker_apt_key_path, sources_path(data))]
    legacy_removed = operations.absent(name="Remove legacy Docker apt files", paths=legacy, present=snap.files)
    operations.apt_remove(
        name="Remove conflicting packages",
        packages=plan.obsolete_to_remove(data.docker_obsolete_packages, snap.packages),
    )
    operations.directory(name=f"apt keyring directory {KEYRING_DIR}", path=KEYRING_DIR, current=snap.files.get(KEYRING_DIR))
    key = apt_key(
        name="Download and verify Docker's apt key",
        url=plan.key_url(data.docker_apt_key_url, data.docker_repo_url, dist),
        path=data.docker_apt_key_path,
        fingerprint=fingerprint,
        sha256=data.docker_apt_key_sha256,
        up_to_date=key_is_current(snap, data.docker_apt_key_path, fingerprint, data.docker_apt_key_sha256),
    )
    source = operations.file(
        name="Write the Docker apt source",
        path=sources_path(data),
        content=plan.sources_text(
            plan.repo_uri(data.docker_repo_url, dist),
            codename,
            data.docker_apt_release_channel,
            arch,
            data.docker_apt_key_path,
        ),
        current=snap.files.get(sources_path(data)),
    )
    operations.run(
        name="apt update for the Docker repository",
        script=operations.APT_UPDATE,
        _if=any_changed(key, source, legacy_removed),
    )
