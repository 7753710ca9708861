"""Test fixtures: what a successful run of the gpu role leaves on a host
(with the driver it needs: a loaded NVIDIA driver, nvidia-smi working)."""

import base64

import roles.gpu.plan as plan
from robotfleet.host import aptrepo
from robotfleet.host.fixtures import file_state
from robotfleet.host.snapshot import FileState
from roles import gpu

DRIVER = "NVRM version: NVIDIA UNIX x86_64 Kernel Module  550.54.14  Thu Feb 22 01:44:30 UTC 2024"


def _b64(text: str) -> str:
    return base64.b64encode(text.encode()).decode()


def converged(play, host: str) -> None:
    data, snap = play.data, play.snapshot
    snap.probes.setdefault(
        gpu.READINGS, f"driver={_b64(DRIVER)}\nsmi_rc=0\nsmi={_b64('GPU 0: NVIDIA (UUID: GPU-1)')}\n"
    )
    snap.packages.update({plan.TOOLKIT: data.gpu_toolkit_version or "1", "gpg": "2"})
    repo = gpu.repository(data, snap.arch)
    snap.files.update(
        {
            "/etc/apt/keyrings": FileState("dir", None, "755", "root", "root"),
            repo.key_path: FileState("file", "0" * 64, "644", "root", "root"),
            repo.sources_path: file_state(repo.sources),
        }
    )
    snap.probes[gpu.KEY_PROBE] = f"{repo.fingerprint}\n{aptrepo.CANONICAL}\n"
