"""What the fault modules share (test_faults_release.py, test_faults_boot.py):
the payload's directory on a robot, a fleet naming another payload tag, a
pyinfra run the test does not wait for, the shell conditions a power cut
waits on, and an image with a layer no robot has seen."""

from __future__ import annotations

import io
import os
import signal
import subprocess
import tarfile

from tests.fixtures import start_pyinfra

DIR = "/var/lib/robot-payload"
LAB_TAG = 'payload_image: "@registry@/ros/payload:1.0"'


def image(tag_or_ref: str) -> dict[str, str]:
    ref = tag_or_ref if "/" in tag_or_ref else f"@registry@/ros/payload:{tag_or_ref}"
    return {LAB_TAG: f'payload_image: "{ref}"'}


class Background:
    """A pyinfra run the test does not wait for (a deploy racing another, or
    one the power cut interrupts)."""

    def __init__(self, lab, *args: str, fleet=None, script: str = "deploy.py"):
        env = dict(os.environ, ROBOT_LAB_PREFIX=lab.prefix, PYINFRA_PROGRESS="off")
        if fleet:
            env["ROBOT_LAB_FLEET"] = str(fleet)
        self.proc = start_pyinfra(
            "-y",
            "inventories/lab.py",
            script,
            *args,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            start_new_session=True,
        )

    def wait(self, seconds: float = 300) -> tuple[int, str]:
        output, _ = self.proc.communicate(timeout=seconds)
        return self.proc.returncode, output

    def kill(self):
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGKILL)
        self.proc.communicate()


NEW_CONTAINERS = (
    "docker ps -aq --filter label=com.docker.compose.project=robot-payload"
    " --filter label=org.opencontainers.image.version={version} | grep -q ."
)  # the one compose up that switches has created the new release's containers (the old ones may still run)

HEALTH_WAIT = (
    f'grep -q \'"state": "switching"\' {DIR}/current/record.json 2>/dev/null'
    " && docker ps -q --filter label=com.docker.compose.project=robot-payload --filter health=starting | grep -q ."
)  # `current` switched, its container up, its verdict not given yet


def build_image_with_a_new_layer(lab, size: int = 1 << 20, tag: str = "1.1-big") -> str:
    """ros/payload:1.1 plus ``size`` bytes the robot has never seen (every lab
    tag shares its layers, so only a new layer makes a pull write to disk)."""
    import docker

    engine = docker.from_env()
    context = io.BytesIO()
    with tarfile.open(fileobj=context, mode="w") as tar:
        for name, data in (("Dockerfile", b"FROM ros/payload:1.1\nCOPY blob /blob\n"), ("blob", os.urandom(size))):
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
    context.seek(0)
    local = f"{lab.state['registry_local']}/ros/payload"
    engine.images.build(fileobj=context, custom_context=True, tag=f"{local}:{tag}", rm=True)
    for line in engine.images.push(local, tag=tag, stream=True, decode=True):
        assert "error" not in line, line
    return tag
