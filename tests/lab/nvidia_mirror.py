"""A signed apt repository laid out like https://nvidia.github.io/libnvidia-container,
served beside the Docker CE mirror, and a driver stand-in for lab hosts.

No GPU exists in the lab and NVIDIA's repository is not reachable, so:

- the repository has NVIDIA's layout (``libnvidia-container/gpgkey`` and the
  flat repository ``libnvidia-container/stable/deb/amd64/`` with InRelease,
  Release(.gpg), Packages(.gz) and the debs), signed by the lab's own key;
- its one package is a STAND-IN named ``nvidia-container-toolkit`` built
  here: ``/usr/bin/nvidia-container-runtime`` is a script that execs runc.
  It is not NVIDIA software and injects no GPU into a container;
- ``fake_driver_script()`` gives a lab host what a loaded driver shows the
  gpu role: a driver version file (at a path the role reads from the setting
  ``gpu_driver_version_file``, since /proc cannot be written in a container)
  and an ``nvidia-smi`` script.  Both say "robot lab stand-in".

``build_into(root)`` adds the repository under the mirror root (idempotent).
"""

from __future__ import annotations

import fcntl
import gzip
import hashlib
import json
import shutil
import subprocess
import time
from pathlib import Path

from .mirror import HASHES, LabKey, file_hashes, format_paragraph, packages_entry, release_date

ARCH = "amd64"
TOP = "libnvidia-container"
CHANNEL = "stable"
PACKAGE = "nvidia-container-toolkit"
VERSION = "1.17.8-1+robotlab.standin"
KEY_UID = "Robot Lab NVIDIA-style Mirror (lab only, not NVIDIA) <nvidia-mirror@robot-lab.invalid>"
MAINTAINER = "Robot Lab NVIDIA stand-in <nvidia-mirror@robot-lab.invalid>"
MANIFEST = ".robot-lab-manifest.json"
FAKE_DRIVER_FILE = "/etc/robot-lab/nvidia-driver-version"
FAKE_NVIDIA_SMI = "/usr/local/bin/nvidia-smi"
FAKE_DRIVER_VERSION = "550.54.14"

RUNTIME_SCRIPT = """#!/bin/sh
# ROBOT LAB STAND-IN for NVIDIA's nvidia-container-runtime (not NVIDIA software).
# It only hands the OCI call to runc: no GPU is injected into the container.
exec runc "$@"
"""

CONTROL = {
    "Package": PACKAGE,
    "Version": VERSION,
    "Architecture": ARCH,
    "Maintainer": MAINTAINER,
    "Section": "utils",
    "Priority": "optional",
    "Description": "ROBOT LAB STAND-IN for nvidia-container-toolkit (not NVIDIA software)\n"
    " Built by tests/lab/nvidia_mirror.py so the gpu role installs a package\n"
    " named like NVIDIA's through the same apt path.  Its\n"
    " nvidia-container-runtime execs runc; it injects no GPU.",
}


class NvidiaKey(LabKey):
    """The lab's own signing key for this repository (not the Docker mirror's)."""

    def ensure(self) -> str:
        if not self.fingerprint():
            self.gpg(
                "--passphrase",
                "",
                "--pinentry-mode",
                "loopback",
                "--quick-gen-key",
                KEY_UID,
                "ed25519",
                "sign",
                "never",
            )
        return self.fingerprint()


def recipe() -> str:
    return hashlib.sha256(Path(__file__).read_bytes()).hexdigest()


def build_deb(out: Path, work: Path) -> Path:
    tree = work / "pkg"
    shutil.rmtree(tree, ignore_errors=True)
    (tree / "DEBIAN").mkdir(parents=True)
    (tree / "DEBIAN" / "control").write_text(format_paragraph(CONTROL))
    runtime = tree / "usr" / "bin" / "nvidia-container-runtime"
    runtime.parent.mkdir(parents=True)
    runtime.write_text(RUNTIME_SCRIPT)
    runtime.chmod(0o755)
    doc = tree / "usr" / "share" / "doc" / PACKAGE / "README.robot-lab"
    doc.parent.mkdir(parents=True)
    doc.write_text(CONTROL["Description"].replace("\n ", "\n") + "\n")
    deb = out / f"{PACKAGE}_{VERSION}_{ARCH}.deb"
    subprocess.run(
        ["dpkg-deb", "--root-owner-group", "-Zgzip", "-b", str(tree), str(deb)], check=True, capture_output=True
    )
    shutil.rmtree(tree)
    return deb


def release_text(indexes: dict[str, bytes]) -> str:
    """Release of a flat repository (no Suite/Codename/Components, like NVIDIA's)."""
    lines = [
        "Origin: robot-lab",
        "Label: Robot lab stand-in for NVIDIA's libnvidia-container repository",
        f"Architectures: {ARCH}",
        f"Date: {release_date(time.time())}",
    ]
    for field, algo in HASHES:
        lines.append(f"{field}:")
        for path, data in sorted(indexes.items()):
            lines.append(f" {file_hashes(data)[algo]} {len(data):>16} {path}")
    return "\n".join(lines) + "\n"


def build_into(root: Path) -> dict:
    """Add ``<root>/libnvidia-container`` (kept while its recipe holds)."""
    root = Path(root)
    top = root / TOP
    with open(root.parent / ".nvidia-mirror.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        manifest_path = top / MANIFEST
        if manifest_path.exists():
            manifest = json.loads(manifest_path.read_text())
            if manifest.get("recipe") == recipe():
                return manifest
        staging = root.parent / "nvidia-staging"
        shutil.rmtree(staging, ignore_errors=True)
        flat = staging / CHANNEL / "deb" / ARCH
        flat.mkdir(parents=True)
        deb = build_deb(flat, staging)
        packages = packages_entry(CONTROL, f"./{deb.name}", deb.read_bytes()).encode()
        indexes = {"Packages": packages, "Packages.gz": gzip.compress(packages, mtime=0)}
        for name, data in indexes.items():
            (flat / name).write_bytes(data)
        (flat / "Release").write_text(release_text(indexes))
        key = NvidiaKey(root.parent / "nvidia-gnupg")
        try:
            fingerprint = key.ensure()
            (staging / "gpgkey").write_bytes(key.export_armored())
            key.sign(flat / "Release")
        finally:
            key.stop_agent()
        manifest = {"recipe": recipe(), "fingerprint": fingerprint, "package": PACKAGE, "version": VERSION}
        (staging / MANIFEST).write_text(json.dumps(manifest, indent=2) + "\n")
        shutil.rmtree(top, ignore_errors=True)
        staging.rename(top)
        print(f"[nvidia-mirror] built {top}", flush=True)
        return manifest


def lab_settings(state: dict) -> dict:
    """The gpu settings that point a lab host at this repository and the driver stand-in."""
    manifest = json.loads((Path(state["mirror_dir"]) / TOP / MANIFEST).read_text())
    return {
        "gpu_repo_url": state["mirror_url"].rsplit("/linux", 1)[0] + "/" + TOP,
        "gpu_apt_key_fingerprint": manifest["fingerprint"],
        "gpu_driver_version_file": FAKE_DRIVER_FILE,
    }


def fake_driver_script() -> str:
    """Shell (run as root in a lab host) installing the driver stand-in."""
    line = f"NVRM version: ROBOT LAB STAND-IN (no NVIDIA driver) x86_64 Kernel Module  {FAKE_DRIVER_VERSION}  lab"
    smi = (
        "#!/bin/sh\n# ROBOT LAB STAND-IN for nvidia-smi: no GPU exists here.\n"
        "echo 'GPU 0: Robot lab stand-in (UUID: GPU-00000000-0000-0000-0000-robotlab0000)'\n"
    )
    import base64

    def put(path, text, mode):
        encoded = base64.b64encode(text.encode()).decode()
        return f"echo {encoded} | base64 -d > {path} && chmod {mode} {path}"

    return " && ".join(
        [
            f"mkdir -p {Path(FAKE_DRIVER_FILE).parent}",
            put(FAKE_DRIVER_FILE, line + "\n", "644"),
            put(FAKE_NVIDIA_SMI, smi, "755"),
        ]
    )


def remove_fake_driver_script() -> str:
    return f"rm -f {FAKE_DRIVER_FILE} {FAKE_NVIDIA_SMI}"
