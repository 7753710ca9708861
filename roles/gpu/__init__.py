"""roles/gpu: the NVIDIA container toolkit on GPU robots and laptops.

Runs where ``gpu_vendor: nvidia`` or ``payload_gpu`` is set, before the docker role,
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
not written here: the docker role owns daemon.json, and this role adds the
runtime through the docker role's hook (``plan.daemon_options``), instead of
``nvidia-ctk runtime configure`` rewriting the file behind its back.  The
payload gets the GPUs and the ``nvidia-smi -L`` check through its hooks.
"""

from __future__ import annotations

from pyinfra.api import deploy

import roles.docker.hooks as docker_hooks
import roles.payload.hooks as payload_hooks
from robotfleet import value_kinds
from robotfleet.host import apt, aptrepo, operations
from robotfleet.host.snapshot import SnapshotQuery
from robotfleet.role import Play, Role, StatusPart
from roles.gpu import plan, settings

PREREQUISITES = ["ca-certificates", "curl", "gpg"]
READINGS = "gpu_readings"
KEY_PROBE = "gpu_key_fingerprints"


def sources_path(data) -> str:
    return f"{aptrepo.SOURCES_DIR}/{data.gpu_apt_filename}.sources"


def repository(data, arch: str) -> aptrepo.Repository:
    return aptrepo.Repository(
        what="NVIDIA",
        key_url=plan.key_url(data.gpu_apt_key_url, data.gpu_repo_url),
        key_path=data.gpu_apt_key_path,
        fingerprint=value_kinds.normal_fingerprint(data.gpu_apt_key_fingerprint),
        fingerprint_setting="gpu_apt_key_fingerprint",
        sources_name=data.gpu_apt_filename,
        sources=plan.sources_text(plan.repo_uri(data.gpu_repo_url, data.gpu_apt_channel, arch), data.gpu_apt_key_path),
        probe=KEY_PROBE,
    )


def declare_reads(data, query: SnapshotQuery) -> None:
    query.packages |= set(PREREQUISITES) | {plan.TOOLKIT}
    query.files |= {aptrepo.KEYRING_DIR, data.gpu_apt_key_path, sources_path(data)}
    query.probes[READINGS] = plan.readings_probe(data.gpu_driver_version_file)
    query.probes[KEY_PROBE] = aptrepo.key_probe(
        data.gpu_apt_key_path, value_kinds.normal_fingerprint(data.gpu_apt_key_fingerprint)
    )


@deploy("GPU")
def nvidia_toolkit(play: Play):
    data, snap = play.data, play.snapshot
    readings = plan.parse_readings(snap.probes.get(READINGS, ""))
    problem = plan.driver_problem(readings, data.gpu_driver_version_file)
    if problem:
        operations.fail(name="Check the NVIDIA driver is loaded", message=problem)
        return
    versions = plan.package_versions(data.gpu_toolkit_version)
    if plan.platform(readings) == "jetson":
        apt.apt_install(
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

    apt.apt_install(
        name="Install apt prerequisites for NVIDIA's repository",
        packages=PREREQUISITES,
        installed=snap.packages,
        update_first=True,
    )
    aptrepo.set_up(repository(data, snap.arch), snap)
    apt.apt_install(
        name="Install the NVIDIA container toolkit",
        packages=[plan.TOOLKIT],
        installed=snap.packages,
        versions=versions,
    )


STATUS = StatusPart(
    command=plan.status_command,
    cells=plan.status_cells,
    columns=(("gpu_driver", "GPU DRIVER"), ("gpu_runtime", "GPU RUNTIME")),
    wide=("gpu_driver", "gpu_runtime"),
    order=30,
)

ROLE = Role(
    name="gpu",
    doc="The NVIDIA container toolkit on GPU hosts, its runtime in daemon.json, GPUs for the payload.",
    settings=settings.SETTINGS,
    # First in deploy.py: a host without a loaded driver fails before anything is installed.
    runs_on=plan.wanted,
    reads=declare_reads,
    steps=nvidia_toolkit,
    renamed=settings.RENAMED,
    adds={
        docker_hooks.DAEMON_OPTIONS: plan.daemon_options,
        payload_hooks.SERVICES: plan.payload_services,
        payload_hooks.CHECKS: plan.check_command,
    },
    status=STATUS,
)
