"""roles/gpu: the NVIDIA container toolkit on GPU robots and laptops.

Runs where ``gpu: nvidia`` or ``payload_gpu`` is set, before the docker role,
so a host that cannot have GPU containers fails (that host only, one line)
before anything is installed:

- no NVIDIA driver loaded (``gpu_driver_version_file`` absent, or nvidia-smi
  missing or failing): the tool does not install kernel drivers;
- Jetson (``/etc/nv_tegra_release``): the toolkit JetPack provides is
  installed from the sources L4T configured; NVIDIA's desktop repository is
  not added.

Elsewhere it sets up NVIDIA's repository as NVIDIA documents it (key from
``<repo>/gpgkey``, which must be exactly the pinned key; a deb822 source with
Signed-By for ``<repo>/stable/deb/<arch>``) and installs
``nvidia-container-toolkit``.  The ``nvidia`` runtime entry of daemon.json is
not written here: the docker role owns daemon.json and merges it
(``plan.daemon_options``), instead of ``nvidia-ctk runtime configure``
rewriting the file behind its back.
"""

from __future__ import annotations

from pyinfra import host
from pyinfra.api import deploy
from pyinfra.operations.util import any_changed

from roles import operations
from roles.gpu import aptkey, plan
from roles.hoststate import Snapshot, SnapshotQuery

PREREQUISITES = ["ca-certificates", "curl", "gpg"]
READINGS = "gpu_readings"
KEY_PROBE = "gpu_key_fingerprints"


def sources_path(data) -> str:
    return f"/etc/apt/sources.list.d/{data.gpu_apt_filename}.sources"


def declare_reads(data, query: SnapshotQuery) -> None:
    if not plan.wanted(data):
        return
    query.packages |= set(PREREQUISITES) | {plan.TOOLKIT}
    query.files |= {data.gpu_apt_key_path, sources_path(data)}
    query.probes[READINGS] = plan.readings_probe(data.gpu_driver_version_file)
    query.probes[KEY_PROBE] = aptkey.fingerprints_probe(data.gpu_apt_key_path)


@operations.operation()
def pinned_key(url: str, path: str, fingerprint: str, up_to_date: bool):
    if up_to_date:
        host.noop(f"{path} holds exactly the pinned key")
        return
    yield operations.shell(aptkey.download_script(url, path, fingerprint, "NVIDIA apt", "gpu_apt_key_fingerprint"))


def key_is_current(snap: Snapshot, path: str, fingerprint: str) -> bool:
    current = snap.files.get(path)
    return (
        current is not None
        and current.kind == "file"
        and current.mode == "644"
        and aptkey.only_pinned(snap.probes.get(KEY_PROBE, ""), fingerprint)
    )


@deploy("GPU")
def nvidia_toolkit(snap: Snapshot):
    data = host.data
    readings = plan.parse_readings(snap.probes.get(READINGS, ""))
    problem = plan.driver_problem(readings, data.gpu_driver_version_file)
    if problem:
        operations.fail(name="Check the NVIDIA driver is loaded", message=problem)
        return
    versions = plan.package_versions(data.gpu_toolkit_version)
    if plan.platform(readings) == "jetson":
        operations.apt_install(
            name="Install JetPack's NVIDIA container toolkit (L4T sources, no desktop repository)",
            packages=[plan.TOOLKIT],
            installed=snap.packages,
            versions=versions,
        )
        return
    try:
        plan.check_os(snap.os_release, snap.arch)
    except plan.PlanError as error:
        operations.fail(name="Check the host can run the NVIDIA container toolkit", message=str(error))
        return

    fingerprint = data.gpu_apt_key_fingerprint.replace(" ", "").upper()
    operations.apt_install(
        name="Install apt prerequisites for NVIDIA's repository",
        packages=PREREQUISITES,
        installed=snap.packages,
        update_first=True,
    )
    key = pinned_key(
        name="Download NVIDIA's apt key and check it is exactly the pinned key",
        url=plan.key_url(data.gpu_apt_key_url, data.gpu_repo_url),
        path=data.gpu_apt_key_path,
        fingerprint=fingerprint,
        up_to_date=key_is_current(snap, data.gpu_apt_key_path, fingerprint),
    )
    source = operations.file(
        name="Write the NVIDIA container toolkit apt source",
        path=sources_path(data),
        content=plan.sources_text(
            plan.repo_uri(data.gpu_repo_url, data.gpu_apt_channel, snap.arch), data.gpu_apt_key_path
        ),
        current=snap.files.get(sources_path(data)),
    )
    operations.run(
        name="apt update for NVIDIA's repository",
        script=operations.APT_UPDATE,
        _if=any_changed(key, source),
    )
    operations.apt_install(
        name="Install the NVIDIA container toolkit",
        packages=[plan.TOOLKIT],
        installed=snap.packages,
        versions=versions,
    )
