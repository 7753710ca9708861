"""Running docker and systemctl, and the one exception a step raises."""

import datetime
import subprocess
import sys


class Failure(Exception):
    """A step failed; the message is the line the operator sees."""


class Refusal(Failure):
    """The request was refused before anything was tried (an image for
    another platform, a compose file Docker refuses)."""


def log(message):
    """A line for people (the journal, a terminal); stdout carries the result."""
    print(message, file=sys.stderr, flush=True)


def run(args, check=True, input_text=None, timeout=None):
    proc = subprocess.run(
        args,
        input=input_text,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        universal_newlines=True,
        timeout=timeout,
    )
    if check and proc.returncode != 0:
        raise Failure("{} failed: {}".format(" ".join(args[:3]), (proc.stderr or proc.stdout).strip()[-400:]))
    return proc


def now():
    return datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


def precise_now():
    return datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%S.%fZ")
