"""A lab robot booted from a prepared first-boot image: the lab's host
image with a `robotfleet bundle` unpacked onto its root before its first
start, as an image build would.  The lab adds only what every lab host has
(its apt proxy, the lab key for ops); the robot is in state.json (so
inventories/lab.py lists it) but not in the lab's known_hosts: its host
keys come from its first report (robotfleet pull-enroll), which its
bundle's enrollment key signs."""

from __future__ import annotations

from pathlib import Path

from . import hostimage, hosts, services, state
from .engine import client, put_files


def start(prefix: str, name: str, rootfs_tar: Path) -> dict:
    """Create `<prefix>-<name>`, unpack the bundle onto it, start it; its state.json entry."""
    dc = client()
    lab = state.load(prefix)
    image = hostimage.ensure_host_image(dc)
    container = hosts._create_host(dc, prefix, name, "robots", image)
    put_files(container, {hosts.APT_PROXY_CONF: hosts.apt_proxy_conf(services.container_name(prefix))})
    key = Path(lab["ssh_key"]).with_suffix(".pub").read_text()
    put_files(
        container,
        {f"/home/{hostimage.OPS_USER}/.ssh/authorized_keys": key},
        mode=0o600,
        owner=(hostimage.USER_UIDS[hostimage.OPS_USER],) * 2,
    )
    if not container.put_archive("/", rootfs_tar.read_bytes()):
        raise RuntimeError(f"could not unpack {rootfs_tar} onto {container.name}")
    container.start()
    entry = {
        "name": name,
        "group": "robots",
        "arch": hostimage.NATIVE_ARCH,
        "container": container.name,
        "port": int(container.labels["robot-lab.ssh-port"]),
    }
    lab["hosts"] = [h for h in lab["hosts"] if h["name"] != name] + [entry]
    state.save(lab)
    return entry
