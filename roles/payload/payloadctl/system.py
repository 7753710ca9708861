"""Running docker and systemctl, and the one exception a step raises."""

import datetime
import subprocess


class Failure(Exception):
    """A step failed; the message is the line the operator sees."""


def log(message):
    print(message, flush=True)


def run(args, check=True, input_text=None, timeout=None):
    proc = subprocess.run(
        args, input=input_text, stdout=subprocess.PIPE, stderr=subprocess.PIPE, universal_newlines=True,
        timeout=timeout,
    )
    if check and proc.returncode != 0:
        raise Failure("{} failed: {}".format(" ".join(args[:3]), (proc.stderr or proc.stdout).strip()[-400:]))
    return proc


def now():
    return datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


def precise_now():
    return datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%S.%fZ")
