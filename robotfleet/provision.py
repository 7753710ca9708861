"""A host's run of the roles: check its data, read its state in one
command, then each role's steps in deploy.py's order."""

from __future__ import annotations

from pyinfra import host

from robotfleet import deploy_roles, pyinfra_patches, secrets
from robotfleet.host import operations
from robotfleet.host.snapshot import HostSnapshot, SnapshotQuery
from robotfleet.role import Play, cards

pyinfra_patches.install()

# Earlier releases kept a memo of the snapshot's answers here (root's
# own directory); nothing reads it now, so a host that still holds it has it
# removed once.  /run is emptied at each boot: once every robot has rebooted
# or run a release with this step, it can go.
EARLIER_MEMO = "/run/robotfleet-memo"


def provision(listed) -> None:
    """Run the roles ``listed`` (deploy.py's ROLES) on the current host.

    pyinfra runs deploy.py once per host; robotfleet/deploy_roles.py runs it only to
    read ROLES, and then this does nothing."""
    if deploy_roles.reading():
        return
    roles = cards(listed)
    # The fleet file was checked before connecting; --data overrides were not.
    problems = deploy_roles.registry_of(roles).data_problems(host.data)
    if problems:
        operations.fail(name="Check the host's settings", message="settings: " + "; ".join(problems))
        return
    running = tuple(role for role in roles if role.runs_on(host.data))
    secrets.hold(host.name, secrets.held_in(host.data.dict()).union(*(role.secrets(host.data) for role in running)))
    query = SnapshotQuery(files={EARLIER_MEMO})
    for role in running:
        role.reads(host.data, query)
    play = Play(host.data, host.get_fact(HostSnapshot, **query.as_kwargs()), running)
    refusal = next(filter(None, (role.refuses(host.data, play.snapshot) for role in running)), None)
    if refusal:  # before any role's steps: nothing changes on the host
        operations.fail(name="Check the host can take its roles", message=refusal)
        return
    memo = play.snapshot.files.get(EARLIER_MEMO)
    if memo is not None and memo.kind == "dir" and memo.owner == "root":
        operations.run(f"rm -rf {EARLIER_MEMO}", name="Remove the snapshot memo earlier releases kept")
    # pyinfra's CLI tells operations apart by the line numbers of their call
    # stack, not the file names: the roles' steps are all called from the line
    # below, so each role gets its own place in deploy.py's list (host.loop),
    # the same on every host, whichever roles run there.
    for role in host.loop(roles):
        if role in running:
            role.steps(play)
