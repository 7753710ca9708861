"""What a release is (the spec the deploy sends, kept with each release),
who asks for this run, and the states a release goes through.

The deploy writes the spec from the host's settings; payloadctl keeps it as
releases/<id>/spec.json, so a rollback or a boot recovery brings a release
back with its own name, timeouts and checks, never with defaults repeated
here."""

import collections
import json
import socket

# A release's states (record.json "state"):
SWITCHING = "switching"  # current points at it, not yet verified (a power cut here is undone at boot)
ACTIVE = "active"  # verified healthy and running
STAGED = "staged"  # in place without autostart (laptops): nothing to verify
FAILED = "failed"  # failed its health gate or was interrupted before it
SETTLED = (ACTIVE, STAGED)  # passed its gate: what a deploy or a rollback may go back to

FIELDS = (
    "name",  # compose project and unit (<name>.service)
    "dir",  # where the releases live
    "compose",  # the compose document
    "spec_hash",  # what identifies the release (what runs, not how it is updated)
    "autostart",  # run it (robots) or only stage it (laptops)
    "delivery",  # pull or push
    "health_timeout",
    "stable_seconds",
    "pull_timeout",
    "apply_lock_timeout",
    "keep_releases",
    "lock_file",  # the update lock: updates refused while it exists
    "checks",  # [{"command": [...], "failure": "cannot see a GPU"}] run in each container once healthy
    "takeover",  # {"primary": repository, "container": [names], "project": [compose projects]} (takeover.py)
)


class Spec(collections.namedtuple("Spec", FIELDS)):
    """One release's spec, every field required."""

    __slots__ = ()

    @classmethod
    def from_dict(cls, data):
        missing = [name for name in FIELDS if name not in data]
        if missing:
            raise ValueError("the spec lacks {}".format(", ".join(missing)))
        return cls(**{name: data[name] for name in FIELDS})

    def to_dict(self):
        return dict(self._asdict())


class Run(collections.namedtuple("Run", ("run_id", "by", "force", "restart", "host"))):
    """This run: its id (names its result), who asks, whether the update
    lock is overridden, whether the unit must restart (it changed), and the
    robot's name in the fleet (what the operator's lines call it)."""

    __slots__ = ()

    @classmethod
    def from_dict(cls, data):
        return cls(data.get("run_id"), data.get("by") or "unknown", bool(data.get("force")), bool(data.get("restart")),
                   data.get("host") or socket.gethostname())


def load_request(path):
    """The deploy's request file: {"spec": {...}, "run": {...}}."""
    with open(path) as handle:
        request = json.load(handle)
    return Spec.from_dict(request["spec"]), Run.from_dict(request.get("run") or {})
