"""What a release is (the spec the deploy sends, kept with each release)
and who asks for this run (a release's states: lifecycle.py).

The deploy writes the spec from the host's settings; payloadctl keeps it as
releases/<id>/spec.json, so a rollback or a boot recovery brings a release
back with its own name, timeouts and checks, never with defaults repeated
here."""

import collections
import json
import socket

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


RUN_FIELDS = ("run_id", "by", "force", "restart", "host", "deployment", "lock_token")


class Run(collections.namedtuple("Run", RUN_FIELDS, defaults=(None, None))):
    """This run: its id (names its result), who asks, whether the update
    lock is overridden, whether the unit must restart (it changed), the
    robot's name in the fleet (what the operator's lines call it), the
    deployment that asked (a rollout's wave, a pull agent's run: named in
    the result) and the apply lock's token of the run it is part of (lock.py;
    never shown)."""

    __slots__ = ()

    @classmethod
    def from_dict(cls, data):
        return cls(
            data.get("run_id"),
            data.get("by") or "unknown",
            bool(data.get("force")),
            bool(data.get("restart")),
            data.get("host") or socket.gethostname(),
            _deployment(data.get("deployment")),
            data.get("lock_token") if isinstance(data.get("lock_token"), str) else None,
        )

    def __repr__(self):
        return "Run({})".format(
            ", ".join(
                "{}={!r}".format(k, "<hidden>" if k == "lock_token" and v else v) for k, v in self._asdict().items()
            )
        )


def _deployment(value):
    """A deployment's name as the result may carry it: printable, short."""
    if not isinstance(value, str):
        return None
    return "".join(ch for ch in value if ch.isprintable())[:120] or None


def load_request(path):
    """The deploy's request file: {"spec": {...}, "run": {...}}."""
    with open(path) as handle:
        request = json.load(handle)
    return Spec.from_dict(request["spec"]), Run.from_dict(request.get("run") or {})
