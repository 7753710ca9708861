"""The lab's NVIDIA-style repository: NVIDIA's layout, signed by its own key,
one clearly named stand-in package."""

import gzip
import hashlib
import subprocess

from tests.lab import mirror, nvidia_mirror


def test_flat_repository_is_signed_and_indexes_the_stand_in(tmp_path):
    root = tmp_path / "repo"
    root.mkdir()
    manifest = nvidia_mirror.build_into(root)
    top = root / "libnvidia-container"
    flat = top / "stable" / "deb" / "amd64"
    keyring = tmp_path / "key.gpg"
    subprocess.run(["gpg", "--batch", "--dearmor", "-o", str(keyring), str(top / "gpgkey")], check=True)
    verified = subprocess.run(
        ["gpgv", "--keyring", str(keyring), str(flat / "InRelease")], capture_output=True, text=True
    )
    assert verified.returncode == 0, verified.stderr
    release = (flat / "Release").read_text()
    assert "Suite:" not in release and "Components:" not in release  # flat, like NVIDIA's
    packages = (flat / "Packages").read_bytes()
    assert hashlib.sha256(packages).hexdigest() in release
    assert gzip.decompress((flat / "Packages.gz").read_bytes()) == packages
    entry = mirror.parse_paragraphs(packages.decode())[0]
    assert entry["Package"] == "nvidia-container-toolkit" and "STAND-IN" in entry["Description"]
    deb = flat / entry["Filename"]
    assert hashlib.sha256(deb.read_bytes()).hexdigest() == entry["SHA256"]
    listing = subprocess.run(["dpkg-deb", "-c", str(deb)], capture_output=True, text=True, check=True).stdout
    assert "./usr/bin/nvidia-container-runtime" in listing
    script = subprocess.run(["dpkg-deb", "--fsys-tarfile", str(deb)], capture_output=True, check=True).stdout
    assert b'exec runc "$@"' in script
    assert len(manifest["fingerprint"]) == 40
    assert nvidia_mirror.build_into(root) == manifest  # cached while the recipe holds


def test_lab_settings_point_beside_the_docker_mirror(tmp_path):
    root = tmp_path / "repo"
    root.mkdir()
    manifest = nvidia_mirror.build_into(root)
    settings = nvidia_mirror.lab_settings({"mirror_dir": str(root), "mirror_url": "http://lab-services:8080/linux"})
    assert settings == {
        "gpu_repo_url": "http://lab-services:8080/libnvidia-container",
        "gpu_apt_key_fingerprint": manifest["fingerprint"],
        "gpu_driver_version_file": "/etc/robot-lab/nvidia-driver-version",
    }
