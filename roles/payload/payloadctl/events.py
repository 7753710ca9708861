"""Docker's events for the payload's containers, streamed (`docker events`):
the health wait wakes the moment Docker says something happened to them (a
container started or died, its health changed) instead of looking again
only after a pause, so a release Docker calls unhealthy is rolled back at
once.  Without a stream (the CLI cannot start, or its stream ends) the wait
falls back to looking every ``POLL`` seconds."""

import os
import select
import subprocess
import time

POLL = 0.5  # seconds between looks without a stream
# What can change the verdict on a release (health_status covers each change
# of health: starting, healthy, unhealthy).
ACTIONS = ("start", "die", "restart", "oom", "destroy", "health_status")


def command(project, since=None):
    args = [
        "docker",
        "events",
        "--format",
        "{{.Action}}",
        "--filter",
        "type=container",
        "--filter",
        "label=com.docker.compose.project=" + project,
    ]
    for action in ACTIONS:
        args += ["--filter", "event=" + action]
    if since is not None:
        args += ["--since", "{:.6f}".format(since)]  # replayed: nothing since then is missed
    return args


class Events:
    """The stream of ``project``'s container events since ``since`` (a time
    on this robot's clock, Docker's too); a context manager that stops it."""

    def __init__(self, project, since=None):
        try:
            self.proc = subprocess.Popen(
                command(project, since), stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL
            )
        except OSError:
            self.proc = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    @property
    def streaming(self):
        return self.proc is not None and self.proc.poll() is None

    def wait(self, seconds):
        """Return when Docker reports something (True) or after ``seconds``
        (False).  Every event already reported is taken at once: one look
        answers a burst (a recreate's die, destroy and start)."""
        if seconds <= 0:
            return False
        if not self.streaming:
            time.sleep(min(seconds, POLL))
            return False
        fd = self.proc.stdout.fileno()
        if not select.select([fd], [], [], seconds)[0]:
            return False
        if not os.read(fd, 65536):  # the stream ended: poll from now on
            self.close()
        return True

    def close(self):
        if self.proc is None:
            return
        proc, self.proc = self.proc, None
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        proc.stdout.close()
