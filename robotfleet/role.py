"""What a role declares, and what its steps are given.

A role is one folder under roles/ whose ``__init__.py`` defines
``ROLE = Role(...)``; deploy.py lists the roles in the order they run.  The
engine builds everything else from these declarations: the fleet file's
checks, the editors' JSON schema, the defaults pyinfra reads (group_data/),
the settings table (docs/reference/settings.md), the host's one snapshot command, the
status table and the rollout's target.  ARCHITECTURE.md has a worked example.
"""

from __future__ import annotations

import copy
import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from robotfleet.checkers import Checker, Problem

if TYPE_CHECKING:  # annotations only: the pull agent reads Setting without pyinfra
    from robotfleet.host.snapshot import Snapshot, SnapshotQuery

GROUPS = ("robots", "laptops")


class _Unset:
    def __repr__(self) -> str:
        return "UNSET"

    def __deepcopy__(self, memo):
        return self


# The default of a setting whose default is pyinfra's own (ssh_user: the
# operator's user): not written into group_data.
UNSET = _Unset()


@dataclass(frozen=True)
class Setting:
    """One setting of the fleet file: its default, its check, one line of doc.

    ``groups`` gives another default where a host is in that group (robots,
    laptops); ``merge`` says how the layers (all.vars < group vars < host)
    combine when each sets it: None means the last one that sets it wins."""

    name: str
    default: Any
    check: Checker
    doc: str
    groups: Mapping[str, Any] = field(default_factory=dict)
    merge: Callable[[list[Any]], Any] | None = None

    def default_in(self, group: str | None) -> Any:
        value = self.groups.get(group, self.default) if group else self.default
        # A copy only of what a caller could change in place (the fleet check asks for every default of every check).
        return value if isinstance(value, (str, int, float, type(None))) else copy.deepcopy(value)


@dataclass(frozen=True)
class Renamed:
    """A setting's older name, still read, with a note asking to rename it:
    ``old`` is now ``new``.  ``values``: the old name's values (strings),
    each with the new name's value for it; empty: the same values."""

    old: str
    new: str
    values: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class Hook:
    """A place where a role lets other roles add to what it builds, e.g. the
    docker role's daemon.json (the GPU role adds its runtime there).  The
    role that owns the hook says what an addition is called with and returns."""

    name: str
    doc: str


@dataclass(frozen=True)
class Metric:
    """One sample of ``robotfleet status --metrics`` (OpenMetrics): a gauge
    named ``robotfleet_<name>``; the host's labels are added to ``labels``."""

    name: str
    help: str
    value: float
    labels: tuple[tuple[str, str], ...] = ()


@dataclass(frozen=True)
class StatusPart:
    """A role's columns in ``robotfleet status``: a read-only shell
    command run in the host's one status command, and its output as cells;
    ``metrics(row)``, the gauges its cells make (robotfleet/commands/metrics.py);
    ``watch(data)``, paths on the host whose change (lstat, a link's target)
    says its status may have changed: a pull robot's agent reads the status
    again only then, after a release, or at its heartbeat; ``history(row)``,
    what its cells say of the host's past, newest first, as (what, text)
    pairs (the page of ``status --html``)."""

    command: Callable[[Any], str]
    cells: Callable[[str], dict]
    columns: tuple[tuple[str, str], ...] = ()
    wide: tuple[str, ...] = ()  # of its columns' keys, those shown only with ``status -o wide``
    order: int = 50  # where its columns stand in the table, lower first
    metrics: Callable[[dict], list[Metric]] | None = None
    watch: Callable[[Any], list[str]] | None = None
    history: Callable[[dict], list[tuple[str, str]]] | None = None


@dataclass(frozen=True)
class RolloutPart:
    """What a rollout waits for on each host: ``target(data)`` (JSON data
    naming what the host should run) and ``missing(row, target)``: None once
    the host's status row shows it, else why not (one line).
    ``result(row, deployment)``: the role's own structured result of the
    deploy named ``deployment`` (see ``deployment()``) as the host's status
    row carries it, ``(ok, why)``; None when the row holds none for it."""

    target: Callable[[Any], Any]
    missing: Callable[[dict, Any], str | None]
    result: Callable[[dict, str], tuple[bool, str] | None] | None = None


# A deploy started by robotfleet (a rollout's wave) is named in this
# environment variable; a role that records results on the host records the
# name with them, so the results of *this* deploy are told from older ones.
DEPLOYMENT_ENV = "ROBOTFLEET_DEPLOYMENT"


def deployment() -> str | None:
    """The name of the deploy this run is (None: not named)."""
    return os.environ.get(DEPLOYMENT_ENV) or None


@dataclass(frozen=True)
class PinPart:
    """What a pull release must bind for a role on a host (``robotfleet
    publish``): ``refs(data)``, the references the host runs (e.g. image
    names); ``resolve(data, refs)``, each one's digest now (ref -> digest;
    ValueError with one line when one cannot be read); ``setting``, the
    role's setting through which the deploy is given the pins (ref ->
    digest) so the host runs exactly what the signed release names;
    ``archive(data, ref, digest, machine, path)``, where the role can carry
    its pins on removable media (``robotfleet export``): the pinned thing
    written into the file ``path`` for robots of ``machine``, returning
    what the robot checks once it has it (an image's id)."""

    refs: Callable[[Any], list[str]]
    resolve: Callable[[Any, list[str]], dict[str, str]]
    setting: str
    archive: Callable[[Any, str, str, str, Any], str] | None = None


@dataclass(frozen=True)
class HoldPart:
    """How the pull agent holds a role's own lock on the robot for a whole
    converge run (robotfleet/pull/robot/converge.py): ``command(data,
    token_file)``, the argv that holds it while the command after it runs,
    writing a token to ``token_file`` first ([] when the role has nothing
    on the robot to hold yet); ``setting``, the role's setting through
    which the deploy hands the token to what takes the lock, so the run's
    own steps join it instead of waiting for it."""

    command: Callable[[Any, str], list[str]]
    setting: str


@dataclass(frozen=True)
class SwitchPart:
    """How a pull robot's release is made ready before its maintenance
    window and switched to in it (robotfleet/pull/robot/window_switch.py).
    ``setting``: the role's setting naming a file; in a planning run
    (``pyinfra --dry``) given it, the role's step that would change the
    robot writes its request there instead; ``prepare(data,
    request_file)``: the argv that makes that request ready on the robot
    without running it; ``switch(data, prepared, deployment)``: the argv
    that runs what was prepared, under the role's own checks (the agent
    runs it in the window as it is, without the release's Python);
    ``read(stdout)``: what the prepare said, from its last JSON line, {"ok",
    "outcome", "target", "message"} (None: nothing it could read); the
    switch's last JSON line carries "ok", "outcome" and "message" too."""

    setting: str
    prepare: Callable[[Any, str], list[str]]
    switch: Callable[[Any, str, str], list[str]]
    read: Callable[[str], dict | None]


def _always(data) -> bool:
    return True


def _nothing(*args) -> None:
    return None


def _no_problems(data: dict, refused: frozenset) -> list[Problem]:
    return []


def _no_secrets(data) -> list[str]:
    return []


@dataclass(frozen=True)
class Role:
    """A role's card.  Only ``name`` and ``doc`` are required.

    - ``runs_on(data)``: whether it has anything to do on a host;
    - ``reads(data, query)``: what its steps need to know about the host;
    - ``steps(play)``: its operations, comparing with ``play.snapshot``;
    - ``refuses(data, snapshot)``: why this host must not be changed at all
      (one line), read from its snapshot before any role's steps; None: go on;
    - ``rules(data, refused)``: checks across settings on a host's merged
      data (defaults included); ``refused`` names settings that already have
      a problem, which a rule does not look at again;
    - ``adds``: hook -> what this role adds there (see ``Play.added``);
    - ``status``, ``rollout``, ``pins``: its parts in ``robotfleet status``,
      ``rollout`` and ``publish`` (see StatusPart, RolloutPart, PinPart);
    - ``secrets(data)``: secret values the role holds for a host beyond its
      data (e.g. passwords read from the environment), masked in output
      like the URL passwords of the data (robotfleet/secrets.py);
    - ``hold``: its lock, held by the pull agent for a converge run (HoldPart);
    - ``switch``: its release made ready before a pull robot's window and
      switched to in it (SwitchPart);
    - ``image_helper``: the argv on the robot with which the pull agent puts
      a release's images in place (``image-pull``, ``image-load``: see
      robotfleet/pull/robot/prefetch.py and media.py);
    - ``renamed``: older names of its settings, still read (Renamed)."""

    name: str
    doc: str
    settings: tuple[Setting, ...] = ()
    runs_on: Callable[[Any], bool] = _always
    reads: Callable[[Any, SnapshotQuery], None] = _nothing
    steps: Callable[[Play], None] = _nothing
    refuses: Callable[[Any, Snapshot], str | None] = _nothing
    rules: Callable[[dict, frozenset], list[Problem]] = _no_problems
    adds: Mapping[Hook, Callable] = field(default_factory=dict)
    status: StatusPart | None = None
    rollout: RolloutPart | None = None
    pins: PinPart | None = None
    secrets: Callable[[Any], list[str]] = _no_secrets
    hold: HoldPart | None = None
    switch: SwitchPart | None = None
    image_helper: tuple[str, ...] = ()
    renamed: tuple[Renamed, ...] = ()


def cards(listed) -> tuple[Role, ...]:
    """The Role of each entry of deploy.py's ROLES (a role's package, or its ROLE)."""
    return tuple(getattr(entry, "ROLE", entry) for entry in listed)


def adders(roles, hook: Hook) -> list[Callable]:
    """What ``roles`` add to ``hook``, in their order."""
    return [add for role in roles for where, add in role.adds.items() if where is hook]


def added(roles, hook: Hook, data, *args) -> list:
    """What ``roles`` add to ``hook`` for a host with ``data``."""
    return [add(data, *args) for add in adders(roles, hook)]


def with_additions(roles, hook: Hook, data, value):
    """``value`` with every addition of ``roles`` at ``hook``: passed through
    each in turn (each returns the new value)."""
    for add in adders(roles, hook):
        value = add(data, value)
    return value


@dataclass
class Play:
    """What a role's steps are given: the host's data, its snapshot (read
    once, before any step), and the roles running on this host."""

    data: Any
    snapshot: Snapshot
    roles: tuple[Role, ...] = ()
    events: dict = field(default_factory=dict)

    def added(self, hook: Hook, *args) -> list:
        """What the other roles on this host add to ``hook``."""
        return added(self.roles, hook, self.data, *args)

    def with_additions(self, hook: Hook, value):
        """``value`` with every addition the roles on this host make at ``hook``."""
        return with_additions(self.roles, hook, self.data, value)

    def announce(self, event: Hook, operation) -> None:
        """Tell the roles after this one that ``operation`` may cause
        ``event`` (e.g. Docker restarted): they gate their reaction on it
        with ``_if=any_changed(*play.announced(event))``."""
        self.events.setdefault(event, []).append(operation)

    def announced(self, event: Hook) -> list:
        return list(self.events.get(event, ()))
