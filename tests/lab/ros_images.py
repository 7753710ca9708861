"""Real ROS 1 payload images for the lab, from Debian's archive.

Debian bookworm packages ROS 1 as Noetic's tools (``ros-core`` 1.16:
roscore, roslaunch, rosmaster, rosout; ``python3-rostopic``,
``python3-rosnode``, ``std_msgs``).  mmdebstrap installs them on a minimal
bookworm root filesystem from the Debian archive the lab already uses
(``debian_archive.py``; apt resolves and configures the whole set, where
debootstrap left part of it unconfigured), and ``docker import`` makes the
image: no Docker Hub involved.  No ROS 2 distribution is packaged, so there
is no ROS 2 image.

    ros/noetic-ros-core:<TAG>   roscore, rostopic, rosnode, std_msgs, procps
    ros/noetic-rviz:<TAG>       rviz and Mesa's drivers (software rendering where
                                the container has no GPU): the laptop's GUI payload

Cached like the host images: the local tag is a hash of the recipe (suite,
archive, packages), built once per machine under the machine-wide lock.

    ensure(lab_state[, RVIZ]) -> the reference the lab's hosts pull (pushed first)

CLI: python3 -m tests.lab.ros_images [--prefix lab] [--image rviz]   (builds; pushes when that lab is up)
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from dataclasses import dataclass

from .engine import LabError, client, get_or_none, timed_phase
from .hostimage import BUILD_DIR, debian_url, recipe_hash
from .machinelock import machine_lock

SUITE = "bookworm"
PACKAGES = ("ros-core", "python3-rostopic", "python3-rosnode", "python3-std-msgs", "procps")
# Documentation, manual pages and translations are a third of the tree and no node reads them.
EXCLUDED_PATHS = ("/usr/share/doc/*", "/usr/share/man/*", "/usr/share/locale/*", "/usr/share/info/*")
LOCAL_REPO = "robot-lab-ros"
REPOSITORY = "ros/noetic-ros-core"
TAG = "1.16-bookworm"
# The environment docker import would otherwise leave empty.
ENV = ("PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin", "LANG=C.UTF-8")


@dataclass(frozen=True)
class Image:
    """One image: its packages, local repository, lab repository and tag, command."""

    packages: tuple[str, ...]
    local_repo: str
    repository: str
    tag: str
    command: str


ROS_CORE = Image(PACKAGES, LOCAL_REPO, REPOSITORY, TAG, "roscore")
# rviz 1.14 and the Mesa drivers its OpenGL view needs (llvmpipe, software, where no GPU is passed in);
# no ros-core: it connects to a robot's roscore.  493 MB; 234 s wall, 79 CPU s to build here.
RVIZ = Image(("rviz", "libgl1-mesa-dri", "procps"), "robot-lab-rviz", "ros/noetic-rviz", "1.14-bookworm", "rviz")
IMAGES = {"ros-core": ROS_CORE, "rviz": RVIZ}


def recipe(image: Image = ROS_CORE) -> dict:
    return {"suite": SUITE, "mirror": debian_url(), "include": list(image.packages), "exclude": list(EXCLUDED_PATHS)}


def local_tag(image: Image = ROS_CORE) -> str:
    return f"{image.local_repo}:{recipe_hash(recipe(image))}"


def mmdebstrap_command(out: str, image: Image = ROS_CORE) -> list[str]:
    command = ["mmdebstrap", "--mode=root", "--variant=minbase", "--include=" + ",".join(image.packages)]
    command += [f"--dpkgopt=path-exclude={path}" for path in EXCLUDED_PATHS]
    return command + [SUITE, out, debian_url()]


def build(dc=None, image: Image = ROS_CORE) -> str:
    """The local tag of the image, built when this machine has none of its recipe."""
    dc = dc or client()
    tag = local_tag(image)
    if get_or_none(dc.images, tag) is not None:
        return tag
    with machine_lock(f"image {tag}"):  # another lab may be building it: wait, then use its build
        if get_or_none(dc.images, tag) is not None:
            return tag
        BUILD_DIR.mkdir(parents=True, exist_ok=True)
        log_path = BUILD_DIR / f"{image.local_repo}-mmdebstrap.log"
        with timed_phase(f"build ROS image {tag} (mmdebstrap {SUITE}: {', '.join(image.packages)})"):
            with open(log_path, "wb") as log:
                try:  # the root filesystem as a tar on stdout, straight into the engine
                    tar = subprocess.Popen(mmdebstrap_command("-", image), stdout=subprocess.PIPE, stderr=log)
                except FileNotFoundError:
                    raise LabError(
                        "cannot build the ROS image: mmdebstrap is not installed (apt-get install mmdebstrap)"
                    ) from None
                repo, _, version = tag.partition(":")
                changes = [f"ENV {env}" for env in ENV] + [f'CMD ["{image.command}"]']
                try:
                    dc.api.import_image_from_stream(tar.stdout, repository=repo, tag=version, changes=changes)
                finally:
                    tar.stdout.close()
                    if tar.wait() != 0:
                        raise LabError(f"mmdebstrap {SUITE} failed (exit {tar.returncode}); see {log_path}")
    return tag


def push(registry_local: str, dc=None, image: Image = ROS_CORE) -> None:
    """Tag the image as <registry_local>/<repository>:<tag> and push it (layers already there are skipped)."""
    dc = dc or client()
    built = dc.images.get(build(dc, image))
    remote = f"{registry_local}/{image.repository}"
    built.tag(remote, tag=image.tag)
    for line in dc.images.push(remote, tag=image.tag, stream=True, decode=True):
        if "error" in line:
            raise LabError(f"pushing {remote}:{image.tag} failed: {line['error']}")


def ensure(lab_state: dict, image: Image = ROS_CORE) -> str:
    """The image in the lab's registry; returns the reference its hosts pull."""
    started = time.monotonic()
    build(image=image)  # outside the push's lock: another lab may be building it (its own lock)
    with machine_lock(f"ros image push {lab_state['registry_local']}"):  # one lab's registry, one push at a time
        push(lab_state["registry_local"], image=image)
    where = f"{image.repository}:{image.tag} in {lab_state['registry_local']}"
    print(f"[ros] {where} ({time.monotonic() - started:.1f} s)", flush=True)
    return f"{lab_state['registry']}/{image.repository}:{image.tag}"


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python3 -m tests.lab.ros_images", description=__doc__.split("\n\n")[0])
    parser.add_argument("--prefix", help="also push to this lab's registry (the lab must be up)")
    parser.add_argument("--image", choices=sorted(IMAGES), default="ros-core", help="which image (default ros-core)")
    args = parser.parse_args(argv)
    image = IMAGES[args.image]
    try:
        if args.prefix:
            from . import state

            print(ensure(state.load(args.prefix), image))
        else:
            print(build(image=image))
    except LabError as error:
        print(f"ros image: {error}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
