"""The lab's git server for pull mode: `<prefix>-git`, gitolite3 from Debian.

Started only when asked (`up --git-server`, or a test that needs it): the
default lab does not wait for it.  It runs sshd (systemd as PID 1, like the
hosts) on `<prefix>-net`, where the robots reach it as `<prefix>-git:22`,
and on a fixed 127.0.0.1 port for this machine.  The lab key is gitolite's
admin (user `admin`): the operator changes keys and rules by pushing
gitolite-admin (robotfleet/pull/operator/gitolite.py), as with a real server.

Its host keys are in `.lab/<prefix>/git_known_hosts`, under both names.
"""

from __future__ import annotations

import uuid
from pathlib import Path
from typing import TYPE_CHECKING

import robotfleet
from robotfleet.pull.operator import gitolite

from . import apt_install, hostimage, sshd, state
from .engine import LabError, get_or_none, pick_free_port, published_ports, put_files, timed_phase
from .machinelock import PORTS_LOCK, machine_lock

if TYPE_CHECKING:
    import docker

GIT_REPO_IMAGE = "robot-lab-git"
PACKAGES = ("gitolite3", "git")
USER = "gitolite3"
HOME = "/var/lib/gitolite3"
FLEET_REPO = "fleet"
PORT_START = 24001
READY_TIMEOUT_S = 90
# The file's name is the admin's gitolite user name.
ADMIN_KEY_IN_CONTAINER = "/etc/robot-lab/admin.pub"

# gitolite3 asks debconf for an admin key: none at build time (each lab has its own).
INSTALL_SCRIPT = f"""set -eu
{apt_install.script(PACKAGES)}# What the package's postinst does when given a key: its user, owning its home.
adduser --quiet --system --home {HOME} --shell /bin/bash --gecos 'git repository hosting' --group {USER}
install -d -o {USER} -g {USER} -m 0750 {HOME}
apt-get clean
rm -rf /var/lib/apt/lists/*
"""

_DOCKERFILE = """FROM {host}
COPY install.sh /tmp/install.sh
RUN sh /tmp/install.sh && rm /tmp/install.sh
"""

# Its git's settings, for every repository it serves: a push holding an
# object git's fsck finds malformed is refused whole (docs/guides/pull.md).
GIT_CONFIG = {"receive.fsckObjects": "true"}
# robotfleet's hooks, as a fleet's git server has them: in gitolite's common
# hooks, linked into every repository.  post-receive: the read copy of
# sharded reports (docs/guides/pull.md, "The reports' read copy");
# pre-receive: a report that is not one report.json of at most 256 KiB is
# refused ("What the git server takes from a robot").
HOOKS = ("post-receive", "pre-receive")
HOOK_FILES = {hook: robotfleet.CHECKOUT / "files" / "git-server" / hook for hook in HOOKS}
HOOKS_IN_CONTAINER = "/etc/robot-lab"
# gitolite's rc lets the fleet's rules set receive.maxInputSize per repository
# (robotfleet/pull/operator/gitolite.py MAX_INPUT); its default lets no git config through.
RC_CONFIG_KEYS = 'sed -i "/^ *GIT_CONFIG_KEYS/s/=>.*/=> \'receive.maxInputSize\',/" "$HOME/.gitolite.rc"'
# Run as the gitolite user once the admin key and the hooks are in place:
# idempotent (a second run replaces the admin key and keeps every repository).
SETUP = " && ".join(
    [
        *(f"git config --file {HOME}/.gitconfig {key} {value}" for key, value in GIT_CONFIG.items()),
        f"cd {HOME} && gitolite setup -pk {ADMIN_KEY_IN_CONTAINER}",
        f"HOME={HOME} {RC_CONFIG_KEYS}",
        *(f"install -m 0755 {HOOKS_IN_CONTAINER}/{hook} {HOME}/.gitolite/hooks/common/{hook}" for hook in HOOKS),
        "gitolite setup --hooks-only",
    ]
)


# OpenSSH >= 9.8 refuses for a while an address whose connections keep
# failing to authenticate (PerSourcePenalties): a robot waiting for its
# enrollment fails at each check, and robots behind one NAT share an
# address.  A fleet's git server exempts the fleet's networks (step 1 of
# docs/guides/pull-from-nothing.md); the lab's robots are on private docker networks.
PENALTY_EXEMPT = "/etc/ssh/sshd_config.d/robotfleet-fleet-networks.conf"
EXEMPT_NETWORKS = "10.0.0.0/8,172.16.0.0/12,192.168.0.0/16"
# sshd drops connections beyond 10 not yet logged in (MaxStartups 10:30:100):
# thousands of robots' checks and pushes come in bursts (docs/guides/pull.md).
STARTUPS = "/etc/ssh/sshd_config.d/robotfleet-fleet-scale.conf"
EXEMPT = (
    f"printf 'MaxStartups 100:30:200\\n' > {STARTUPS} && "
    f"printf 'PerSourcePenaltyExemptList {EXEMPT_NETWORKS}\\n' > {PENALTY_EXEMPT} && "
    f"{{ sshd -t 2>/dev/null || rm -f {PENALTY_EXEMPT}; }} && systemctl reload ssh.service"  # older sshd: no penalties
)


def container_name(prefix: str) -> str:
    return f"{prefix}-git"


def recipe() -> dict:
    return {
        "host": hostimage.host_recipe(),
        "packages": list(PACKAGES),
        "script": INSTALL_SCRIPT,
        "dockerfile": _DOCKERFILE,
    }


def image_tag() -> str:
    return f"{GIT_REPO_IMAGE}:{hostimage.recipe_hash(recipe())}"


def ensure_image(dc: docker.DockerClient) -> str:
    """The git server's image, built once per recipe (on the host image)."""
    tag = image_tag()
    if hostimage.image_exists(dc, tag):
        return tag
    host = hostimage.ensure_host_image(dc)
    with machine_lock(f"image {tag}"), timed_phase(f"build git server image {tag}"):
        if hostimage.image_exists(dc, tag):  # another lab built it meanwhile
            return tag
        hostimage.build_image(dc, tag, _DOCKERFILE.format(host=host), {"install.sh": INSTALL_SCRIPT})
    return tag


def known_hosts_lines(names: list[str], public_keys: list[str]) -> list[str]:
    """known_hosts lines naming the server by each of ``names``."""
    return [f"{','.join(names)} {' '.join(key.split()[:2])}" for key in public_keys]


def ensure(dc: docker.DockerClient, prefix: str, key_path: Path) -> dict:
    """Start (or reuse) the git server of a running lab; returns what
    state.json keeps under "git"."""
    image = ensure_image(dc)
    name = container_name(prefix)
    container = get_or_none(dc.containers, name)
    if container is not None and container.labels.get("robot-lab.image") != image:
        container.remove(force=True)
        container = None
    if container is None:
        with machine_lock(PORTS_LOCK):  # the port is taken once the container exists
            port = pick_free_port(PORT_START, published_ports(dc))
            container = hostimage.create_systemd_container(
                dc,
                image,
                name,
                hostname="git",
                network=f"{prefix}-net",
                labels={
                    "robot-lab.prefix": prefix,
                    "robot-lab.role": "git",
                    "robot-lab.image": image,
                    "robot-lab.ssh-port": str(port),
                },
                ports={22: port},
                volumes={},
            )
        put_files(container, {"/etc/machine-id": uuid.uuid4().hex + "\n"})
    if container.status != "running":
        container.start()
    port = int(container.labels["robot-lab.ssh-port"])
    with timed_phase("git server (gitolite3)"):
        keys = sshd.wait_for_host_keys(container, READY_TIMEOUT_S)
        put_files(container, {ADMIN_KEY_IN_CONTAINER: key_path.with_suffix(".pub").read_text()})
        hooks = {f"{HOOKS_IN_CONTAINER}/{hook}": path.read_text() for hook, path in HOOK_FILES.items()}
        put_files(container, hooks, mode=0o755)
        code, out = container.exec_run(["su", "-s", "/bin/sh", USER, "-c", SETUP])
        if code != 0:
            raise LabError(f"{name}: gitolite setup failed: {out.decode(errors='replace').strip()[-300:]}")
        code, out = container.exec_run(["sh", "-c", EXEMPT])
        if code != 0:
            raise LabError(f"{name}: sshd's exemption for the lab's networks: {out.decode(errors='replace')[-300:]}")
        known_hosts = state.lab_dir(prefix) / "git_known_hosts"
        known_hosts.write_text("\n".join(known_hosts_lines([f"[127.0.0.1]:{port}", name], keys)) + "\n")
        git = {
            "container": name,
            "host": name,
            "port": port,
            "user": USER,
            "repo": FLEET_REPO,
            "known_hosts": str(known_hosts),
            "host_keys": keys,
        }
        gitolite.update(admin(git, key_path), FLEET_REPO, message="robotfleet: the lab's fleet repository")
    return git


def admin(git: dict, key_path: Path | str) -> gitolite.Admin:
    """The lab key as gitolite's admin, from this machine."""
    return gitolite.Admin(f"ssh://{git['user']}@127.0.0.1:{git['port']}", str(key_path), git["known_hosts"])


def robot_url(git: dict) -> str:
    """The fleet repository as the robots reach it on the lab network."""
    return f"ssh://{git['user']}@{git['host']}/{git['repo']}"


def local_url(git: dict) -> str:
    """The fleet repository as this machine reaches it."""
    return f"ssh://{git['user']}@127.0.0.1:{git['port']}/{git['repo']}"


def register_robot(prefix: str, robot: str, public_key: str, enrollment: bool = False) -> bool:
    """Let ``robot`` (its gitolite user) read the fleet repository and write
    only refs/reports/<robot>, with ``public_key``."""
    lab = state.load(prefix)
    git = lab.get("git")
    if not git:
        raise LabError(f"lab '{prefix}' has no git server: python3 -m tests.lab up --git-server")
    try:
        return gitolite.register(admin(git, lab["ssh_key"]), git["repo"], robot, public_key, enrollment)
    except gitolite.GitoliteError as error:
        raise LabError(str(error)) from None
