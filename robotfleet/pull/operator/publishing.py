"""A release from the fleet file, the deploy code at a commit and what the
roles pin; published, halted or renewed in a release repository.

The engine names no role: the images a release binds come from each role's
``pins`` part (robotfleet/role.py PinPart); the payload role resolves its
images to digests through its registry client.  The pull hosts are the
fleet file's hosts with ``pull_enabled: true`` (an engine setting); their
platforms (``pull_platform``) say which wheelhouses the release carries.
"""

from __future__ import annotations

import datetime
import hashlib
from dataclasses import dataclass, field, replace
from pathlib import Path

from robotfleet import secrets
from robotfleet.fleet import pull_mode
from robotfleet.fleet.validate import Fleet, FleetError, parse
from robotfleet.pull.operator import wheels
from robotfleet.pull.operator.repository import Expiry, Repository, RepositoryError
from robotfleet.pull.protocol import record as records
from robotfleet.pull.protocol import tree, waves
from robotfleet.pull.protocol.robot_data import HostData

DEFAULT_FLEET = "inventories/robots.yaml"


class PublishError(Exception):
    """The release cannot be published; the message is one line (or a fleet file's lines)."""


@dataclass(frozen=True)
class Options:
    """What `robotfleet publish` was asked (each has a default)."""

    revision: str = "HEAD"
    fleet: str = DEFAULT_FLEET  # the fleet file, as a path in the commit
    plan: waves.Plan = waves.Plan()
    pause_from_checks: bool = False  # the plan's pause: the robots' longest check period (longest_check)
    expiry: Expiry = Expiry()
    wheel_cache: Path | None = None  # None: no wheels (tests; robots then need an index)
    index_url: str | None = None
    refresh_wheels: bool = False  # ask the index even when the cache holds every requirement
    # Publish the commit though the deploy paths have uncommitted changes: they
    # are left out (a release is a commit, as reviewed), and named (uncommitted).
    leave_out_uncommitted: bool = False
    platforms: tuple[str, ...] = field(default_factory=tuple)  # beyond the pull hosts' own


def pull_hosts(fleet: Fleet, registry) -> list[tuple[str, HostData]]:
    """The fleet's hosts with ``pull_enabled: true``, robots then laptops, in file
    order, with every setting's default for their group under what the file says."""
    merged = [
        (name, HostData({**registry.defaults(group), **data}))
        for group in ("robots", "laptops")
        for name, data in fleet.hosts(group)
    ]
    return [(name, data) for name, data in merged if pull_mode.pulls(data)]


def longest_check(hosts: list[tuple[str, HostData]]) -> int:
    """The longest wait between two checks of the release's robots
    (pull_interval + pull_jitter): the default pause between waves, so that
    every robot of a wave that is on has checked before the next one opens."""
    return max(pull_mode.value(data, "pull_interval") + pull_mode.value(data, "pull_jitter") for _, data in hosts)


def secret_refusal(fleet: Fleet, path: str) -> str | None:
    """The line refusing a release whose fleet file holds a secret (by
    robotfleet/secrets.py's rule), naming the first host and field: the
    file travels in the release's code to every robot, mirror and medium,
    and each robot reads every host's values in it."""
    found = [
        (name, field)
        for group in ("robots", "laptops")
        for name, data in fleet.hosts(group)
        for field, _ in secrets.found_in(data)
    ]
    if not found:
        return None
    name, field = found[0]
    more = f" ({len(found) - 1} more in the file)" if len(found) > 1 else ""
    return (
        f"{path}: {name}.{field} holds a secret{more}, and the fleet file travels in every release to every robot "
        "and mirror: keep it out of the fleet file (payload_secret_files, or an _env/_file form such as "
        "payload_registry_auths' password_file)"
    )


def resolve_pins(roles, hosts: list[tuple[str, HostData]]) -> dict[str, dict[str, str]]:
    """Host -> {reference: digest} from every role's pins part (each
    reference resolved once per role); PublishError naming the host."""
    resolved: dict[tuple[str, str], str] = {}
    result: dict[str, dict[str, str]] = {}
    for name, data in hosts:
        pins: dict[str, str] = {}
        for role in roles:
            if role.pins is None or not role.runs_on(data):
                continue
            refs = list(dict.fromkeys(role.pins.refs(data)))
            wanted = [ref for ref in refs if (role.name, ref) not in resolved]
            if wanted:
                try:
                    found = role.pins.resolve(data, wanted)
                except ValueError as error:
                    raise PublishError(f"{name}: {role.name}: {error}") from None
                missing = [ref for ref in wanted if ref not in found]
                if missing:
                    raise PublishError(f"{name}: {role.name}: no digest for {missing[0]}")
                resolved.update({(role.name, ref): found[ref] for ref in wanted})
            pins.update({ref: resolved[(role.name, ref)] for ref in refs})
        result[name] = pins
    return result


def uncommitted(checkout, revision: str) -> list[str]:
    """What a release of ``revision`` leaves out of the working tree: the
    deploy paths' uncommitted changes when it is HEAD (else nothing of the
    working tree was to be published)."""
    try:
        commit = tree.resolve(checkout, revision)
        return dirty(checkout) if commit == tree.resolve(checkout, "HEAD") else []
    except tree.TreeError:
        return []  # build names the revision


def dirty(checkout, paths=tree.DEPLOY_PATHS) -> list[str]:
    """Tracked files of the deploy paths changed in the working tree (git status)."""
    listed = tree.git(checkout, "status", "--porcelain", "--untracked-files=no", "--", *paths)
    return [line[3:] for line in listed.decode(errors="replace").splitlines() if line.strip()]


def read_fleet(checkout, commit: str, path: str, registry) -> tuple[Fleet, str]:
    """The fleet file as the commit has it, checked; (fleet, its sha256)."""
    try:
        data = tree.blob(checkout, commit, path)
    except tree.TreeError:
        raise PublishError(
            f"{path}: not in commit {commit[:12]} (commit the fleet file: robots get it from the release's code)"
        ) from None
    try:
        return parse(data, f"{path}@{commit[:12]}", registry), hashlib.sha256(data).hexdigest()
    except FleetError as error:
        raise PublishError(
            "\n".join(error.lines + [f"{len(error.lines)} problem(s) in the fleet file; nothing was published."])
        ) from None


def build(
    checkout, options: Options, roles, registry, version: int, now: datetime.datetime, work: Path
) -> tuple[records.Record, dict[str, Path]]:
    """The release record and its target files (code archive, wheels, in
    ``work``), checked before anything is signed."""
    try:
        commit = tree.resolve(checkout, options.revision)
    except tree.TreeError:
        raise PublishError(f"{options.revision}: not a commit of {checkout}") from None
    if not options.leave_out_uncommitted and commit == tree.resolve(checkout, "HEAD"):
        changed = dirty(checkout)
        if changed:
            raise PublishError(
                f"{changed[0]}: changed and not committed ({len(changed)} file(s)); robots get the "
                "commit, not the working tree: commit first, or --leave-out-uncommitted to publish the "
                "commit without them"
            )
    fleet, fleet_sha = read_fleet(checkout, commit, options.fleet, registry)
    refused = secret_refusal(fleet, options.fleet)
    if refused:
        raise PublishError(f"{refused}; nothing was published")
    hosts = pull_hosts(fleet, registry)
    if not hosts:
        raise PublishError(f"{options.fleet}: no host has pull_enabled: true; nothing to publish for")
    images = resolve_pins(roles, hosts)
    try:
        archive = work / "code.tar.gz"
        tree.write_archive(checkout, commit, archive)
        tree_sha = tree.tree_sha256(tree.entries_of_commit(checkout, commit))
    except tree.TreeError as error:
        raise PublishError(str(error)) from None
    files = {records.code_path(commit): archive}
    wheel_targets: dict[str, list[str]] = {}
    if options.wheel_cache is not None:
        platforms = sorted({pull_mode.value(data, "pull_platform") for _, data in hosts} | set(options.platforms))
        try:
            requirements = wheels.requirements_of(tree.blob(checkout, commit, "pyproject.toml"))
            for platform in platforms:
                found = wheels.build_wheelhouse(
                    requirements,
                    platform,
                    options.wheel_cache,
                    index_url=options.index_url,
                    refresh=options.refresh_wheels,
                )
                wheel_targets[platform] = [f"wheels/{p.name}" for p in found]
                files.update({f"wheels/{p.name}": p for p in found})
        except (wheels.WheelError, tree.TreeError) as error:
            raise PublishError(str(error)) from None
    try:
        record = records.build(
            version,
            now,
            now + options.expiry.targets,
            commit,
            tree_sha,
            options.fleet,
            fleet_sha,
            [name for name, _ in hosts],
            images,
            wheel_targets,
            replace(options.plan, pause=longest_check(hosts)) if options.pause_from_checks else options.plan,
        )
    except records.RecordError as error:
        raise PublishError(str(error)) from None
    return record, files


def next_version(repository: Repository) -> int:
    current = repository.record() if repository.exists() else None
    return current.version + 1 if current else 1


def publish(
    repository: Repository,
    record: records.Record,
    files: dict[str, Path],
    keys,
    options: Options,
    now: datetime.datetime,
) -> None:
    """Sign ``record`` and its files into ``repository`` (made first, with
    the root key, if it is new)."""
    from robotfleet.pull.operator.keys import ONLINE, ROOT

    try:
        if not repository.exists():
            repository.create(keys.signer(ROOT), keys.signer(ONLINE), options.expiry, now)
        repository.publish(record, files, keys.signer(ONLINE), options.expiry, now)
    except RepositoryError as error:
        raise PublishError(str(error)) from None


def halt(repository: Repository, keys, reason: str, expiry: Expiry, now: datetime.datetime) -> records.Record:
    """A signed halt of the current release: its next version with halt
    true; robots that have not started it do not start."""
    from robotfleet.pull.operator.keys import ONLINE

    try:
        current = repository.record() if repository.exists() else None
        if current is None:
            raise PublishError(f"{repository.path}: no release to halt; there is nothing for robots to stop.")
        if current.halt:
            raise PublishError(
                f"release {current.version} is already halted ({current.halt_reason}); nothing was "
                "changed (a new publish ends the halt)."
            )
        halted = current.halted(current.version + 1, now, now + expiry.targets, reason)
        files = {path: repository.blob(path) for path in halted.targets()}
        repository.publish(halted, files, keys.signer(ONLINE), expiry, now)
    except RepositoryError as error:
        raise PublishError(str(error)) from None
    return halted
