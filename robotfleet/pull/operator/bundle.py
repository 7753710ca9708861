"""A first-boot bundle: what to copy onto a robot's image (or SD card) so
that the robot, booting it for the first time, converges itself to the
current release and reports, with no inbound connection at any point.

    <out>/rootfs.tar                    unpacked onto the image's root (owned by root, modes kept;
                                        of the directories, only the bundle's own)
        etc/robot-pull/agent.json       the robot's name, the fleet remote, the interval... (0600)
        etc/robot-pull/root.json        the release repository's root: its first trust (0600)
        etc/robot-pull/known_hosts      the git server's host keys
        etc/robot-pull/remote-ca.pem    the CA of an https fleet remote (pull_remote_ca), if set
        etc/robot-pull/enroll_ed25519   a single-use enrollment key (0600): the git server accepts
                                        it as this robot until its own key is registered
        var/lib/robot-pull/first-boot/  the current release's code archive and wheels
        etc/systemd/system/...          robot-pull.service and .timer, robot-pull-first-boot.service,
                                        enabled (their wants links)
        usr/local/sbin/robot-pull-first-boot
    <out>/README                        how to put it on an image

At first boot robot-pull-first-boot.service makes the robot's SSH host
keys (ssh-keygen -A) and its own key for the remote, the venv from the
wheels, unpacks the code, and starts the agent; the agent's first report
carries the host keys and the robot's key, from which ``robotfleet
pull-enroll`` writes the fleet's known_hosts and swaps the enrollment key
for the robot's own on the git server.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import shutil
import subprocess
from pathlib import Path

from robotfleet import atomicfile
from robotfleet.fleet import pull_mode
from robotfleet.pull.operator import enrollments
from robotfleet.pull.protocol import agent_files, enrollment, robot_key

FIRST_BOOT = f"{agent_files.STATE}/first-boot"
SCRIPT = "/usr/local/sbin/robot-pull-first-boot"

FIRST_BOOT_UNIT = f"""{agent_files.HEADER}[Unit]
Description=Robot fleet pull agent: first boot (host keys, venv, first check)
Wants=network-online.target
After=network-online.target
ConditionPathExists={FIRST_BOOT}

[Service]
Type=oneshot
ExecStart={SCRIPT}
TimeoutStartSec=1h

[Install]
WantedBy=multi-user.target
"""

# The key's comment: the robot's name, read from its config at boot.
KEY_COMMENT = f'''"robot-pull@$(sed -n 's/.*"robot": "\\([^"]*\\)".*/\\1/p' {agent_files.CONFIG})"'''
FIRST_BOOT_SCRIPT = f"""#!/bin/sh
# robot-pull first boot (robotfleet/pull/operator/bundle.py): this robot's own keys,
# the agent's venv and code from the bundle, then the agent's first check.
set -eu
umask 077
fb={FIRST_BOOT}
state={agent_files.STATE}
say() {{ echo "robot-pull first boot: $*"; }}
ssh-keygen -A
say "host keys: $(cat /etc/ssh/ssh_host_ed25519_key.pub | cut -d' ' -f1-2)"
if ! python3 -c 'import ensurepip, venv' 2>/dev/null || ! command -v git >/dev/null || ! command -v ssh >/dev/null; then
    say "installing python3-venv, git and openssh-client"
    apt-get update -q
    DEBIAN_FRONTEND=noninteractive apt-get install -y -q python3-venv git openssh-client
fi
if [ ! -f {agent_files.KEY} ]; then
{robot_key.keygen_script(KEY_COMMENT)}fi
mkdir -p "$state/venvs" "$state/code"
id=$(cat "$fb/venv-id")
if [ ! -x "$state/venvs/$id/bin/python" ]; then
    rm -rf "$state/venvs/.new-$id"
    python3 -m venv "$state/venvs/.new-$id"
    "$state/venvs/.new-$id/bin/python" -m pip install -q --no-index --no-deps --disable-pip-version-check \\
        "$fb"/wheels/*.whl
    mv -T "$state/venvs/.new-$id" "$state/venvs/$id"
fi
ln -sfn "venvs/$id" "$state/.venv.new" && mv -T "$state/.venv.new" "$state/venv"
tree=$(cat "$fb/tree-id")
if [ ! -d "$state/code/$tree" ]; then
    rm -rf "$state/code/.new-$tree" && mkdir "$state/code/.new-$tree"
    tar -xzf "$fb/code.tar.gz" -C "$state/code/.new-$tree" --no-same-owner
    chmod 0755 "$state/code/.new-$tree"
    mv -T "$state/code/.new-$tree" "$state/code/$tree"
fi
ln -sfn "$tree" "$state/code/.current.new" && mv -T "$state/code/.current.new" "$state/code/current"
rm -rf "$fb"
say "venv $id and deploy tree $tree in place; the agent's first check starts"
systemctl start --no-block {agent_files.SERVICE}
"""

README = """A first-boot bundle for robot {robot} (robotfleet bundle; docs/guides/pull.md).

Put it on the robot's image, as root, with the image mounted at /mnt/image:

    tar -xpf rootfs.tar -C /mnt/image

(or unpack it in your image build: a Debian/Ubuntu image with systemd,
openssh-server and python3; python3-venv and git are installed at first boot
if the image lacks them, which needs its apt sources).  Nothing else: the
units are enabled by their links.  At first boot the robot makes its own SSH
host keys, its venv and its key for the fleet remote, converges to the
current release and reports.  Then, on the operator's side:

    robotfleet pull-enroll INVENTORY --limit {robot} --admin ...

writes its host keys (from its report) to the fleet's known_hosts and
registers its own key with the git server in place of the enrollment key.

etc/robot-pull/enroll_ed25519 in rootfs.tar is a secret: the git server accepts it
as {robot} until then.  Keep this directory, and images made from it, private.
"""


class BundleError(Exception):
    """The bundle cannot be made (one line)."""


def _write(path: Path, data: bytes | str, mode: int = 0o644) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data.encode() if isinstance(data, str) else data)
    os.chmod(path, mode)


def _link(path: Path, target: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.is_symlink():
        path.unlink()
    os.symlink(target, path)


def make(
    out: Path,
    robot: str,
    data,
    record,
    code: Path,
    wheels: list[tuple[str, Path]],
    root: bytes,
    ca: bytes | None = None,
    rule: tuple[str, str] | None = None,
) -> str:
    """Write the bundle for ``robot`` (host ``data``) into ``out`` (which must
    not exist), with the https remote's CA ``ca`` if any; ``rule`` (name rule,
    prefix): for an image shared by robots that name themselves, ``robot``'s
    settings.  The enrollment key's public half."""
    if out.exists():
        raise BundleError(f"{out}: already exists; give a new directory")
    if not wheels:
        raise BundleError(
            f"release {record.version} carries no wheels for {pull_mode.value(data, 'pull_platform')}: the robot could "
            "not make its venv (publish with wheels)"
        )
    out.mkdir(parents=True, mode=0o700)
    rootfs = out / "rootfs"
    etc, first = rootfs / agent_files.ETC.lstrip("/"), rootfs / FIRST_BOOT.lstrip("/")
    (rootfs / agent_files.STATE.lstrip("/")).mkdir(parents=True, mode=0o700)
    etc.mkdir(parents=True, mode=0o700)
    config = agent_files.for_host(data, robot, trusted_time=record.published)
    if rule is not None:
        config = dataclasses.replace(config, robot="", name_rule=rule[0], name_prefix=rule[1])
    _write(etc / "agent.json", config.to_json(), 0o600)
    _write(etc / "root.json", root, 0o600)
    _write(etc / "known_hosts", agent_files.known_hosts(data))
    if ca is not None:
        _write(etc / "remote-ca.pem", ca)
    done = subprocess.run(
        [
            "ssh-keygen",
            "-q",
            "-t",
            "ed25519",
            "-N",
            "",
            "-C",
            f"robot-pull-enroll@{robot}",
            "-f",
            str(etc / "enroll_ed25519"),
        ],
        capture_output=True,
        text=True,
    )
    if done.returncode:
        raise BundleError(f"ssh-keygen: {done.stderr.strip()}")
    (first / "wheels").mkdir(parents=True)
    shutil.copyfile(code, first / "code.tar.gz")
    for name, path in wheels:
        shutil.copyfile(path, first / "wheels" / name)
    _write(first / "tree-id", record.tree_sha256 + "\n")
    venv = agent_files.venv_id((name, hashlib.sha256(path.read_bytes()).hexdigest()) for name, path in wheels)
    _write(first / "venv-id", venv + "\n")
    units = rootfs / agent_files.UNIT_DIR.lstrip("/")
    _write(units / agent_files.SERVICE, agent_files.service_unit())
    _write(units / agent_files.TIMER, agent_files.timer_unit(data))
    _write(units / agent_files.FIRST_BOOT_SERVICE, FIRST_BOOT_UNIT)
    _link(units / "timers.target.wants" / agent_files.TIMER, f"../{agent_files.TIMER}")
    _link(units / "multi-user.target.wants" / agent_files.FIRST_BOOT_SERVICE, f"../{agent_files.FIRST_BOOT_SERVICE}")
    _write(rootfs / SCRIPT.lstrip("/"), FIRST_BOOT_SCRIPT, 0o755)
    public = (etc / "enroll_ed25519.pub").read_text().strip()
    _archive(rootfs, out / "rootfs.tar")
    shutil.rmtree(rootfs)
    _write(
        out / "README",
        README.format(robot=robot if rule is None else f"{rule[1]}<{rule[0]}> (with the settings of {robot})"),
    )
    return public


# The directories the bundle owns; the image's own (etc, usr, var, etc/systemd ...)
# are left out, so that tar -xp neither changes their modes nor their owners.
OWN_DIRECTORIES = (agent_files.ETC.lstrip("/"), agent_files.STATE.lstrip("/"))


def _archive(rootfs: Path, tar_path: Path) -> None:
    """rootfs as a tar owned by root (whoever made it), modes kept but
    never writable by group or others (whatever the operator's umask);
    of the directories, only the bundle's own."""
    import tarfile

    def as_root(info: tarfile.TarInfo) -> tarfile.TarInfo:
        info.uid = info.gid = 0
        info.uname = info.gname = "root"
        if not info.issym():
            info.mode &= ~0o022
        return info

    with tarfile.open(tar_path, "w") as tar:
        for path in sorted(rootfs.rglob("*")):
            name = str(path.relative_to(rootfs))
            if (
                path.is_dir()
                and not path.is_symlink()
                and not any(name == own or name.startswith(own + "/") for own in OWN_DIRECTORIES)
            ):
                continue
            tar.add(path, arcname=name, recursive=False, filter=as_root)
    os.chmod(tar_path, 0o600)


key_sha256 = enrollment.key_sha256  # what the operator keeps of an enrollment key: the hash of its public half


def remember(path: Path, robot: str, public_key: str, release: int) -> None:
    """Note the enrollment key (its hash) among the operator's enrollments (a JSON file); what else is
    kept for ``robot`` (the own key it was enrolled with) stays."""
    kept = enrollments.read_kept(path)
    kept.setdefault(robot, {}).update(enroll_key_sha256=key_sha256(public_key), release=release)
    atomicfile.write(path, json.dumps(kept, indent=1, sort_keys=True) + "\n", mode=0o600, make_parents=True)
